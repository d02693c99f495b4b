"""Markdown tables of bench_results/*.json, for BENCHMARKS.md (so the numbers there are the
measured ones, copied by a program, not by hand).

    python scripts/bench_report.py [--results bench_results]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_common as bc  # noqa: E402

PHASES = ["sort", "stress", "p2g", "halo", "grid", "g2p", "migrate"]


def table(headers, rows) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(bc.fmt(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def load(folder: Path, name: str):
    path = folder / name
    return json.loads(path.read_text()) if path.exists() else None


VECTOR_FLAGS = ("avx512f", "avx512_fp16", "avx2", "fma", "sse4_2")


def machine_line(doc) -> str:
    m = doc["machine"]
    load = ", ".join(f"{x:.2f}" for x in m.get("loadavg_1_5_15min", []))
    flags = m.get("cpu_flags", "").split()
    isa = " ".join(f for f in VECTOR_FLAGS if f in flags) or "flags not recorded"
    launches = doc.get("launch_count")
    runs = f"; {launches} separate launches per scene" if launches else ""
    return (f"_{m['date']}, {m['cpu']} ({isa}), {m['cores']} cores, Python {m['python']}, "
            f"numba {m['numba']}, taichi {m.get('taichi')}, git {m.get('git')}; load average "
            f"at the end {load}{runs}_")


def ratio_range(r: dict, key: str) -> str:
    """"lo-hi" over the separate launches (a single launch: its value and "1 launch")."""
    if f"{key}_range" in r:
        lo, hi = r[f"{key}_range"]
        return f"{lo:.2f}-{hi:.2f}"
    return f"{r[key]:.2f} (1 launch)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default=str(bc.RESULTS))
    args = ap.parse_args(argv)
    folder = Path(args.results)
    peer = load(folder, "peer.json")
    if peer:
        print("### Peer: hpcmpm vs Taichi (CPU, float64, 1 thread)\n")
        print(machine_line(peer) + "\n")
        print(table(
            ["scene", "particles", "hpcmpm ms/step min / median", "Taichi ms/step min / median",
             "hpcmpm M particle-steps/s (median)", "Taichi M particle-steps/s (median)",
             "hpcmpm / Taichi (min), range over launches", "(median), range",
             "max position difference, cells"],
            [[r["scene"], r["particles"],
              f"{r['hpcmpm']['ms_per_step_min']:.3f} / {r['hpcmpm']['ms_per_step_median']:.3f}",
              f"{r['peer']['ms_per_step_min']:.3f} / {r['peer']['ms_per_step_median']:.3f}",
              r["hpcmpm"]["particle_steps_per_s_median"] / 1e6,
              r["peer"]["particle_steps_per_s_median"] / 1e6,
              ratio_range(r, "ratio_hpcmpm_over_peer_min"),
              ratio_range(r, "ratio_hpcmpm_over_peer_median"),
              r["max_position_difference_cells"]] for r in peer["results"]]))
        print("\n(ms/step columns: the first launch; the ratios: their range over all launches)")
        print("\nhpcmpm phase times (ms/step, mean over the timed steps):\n")
        print(table(["scene"] + PHASES + ["sum"],
                    [[r["scene"]] + [r["hpcmpm_phases_ms_per_step"].get(k, 0.0) for k in PHASES]
                     + [sum(r["hpcmpm_phases_ms_per_step"].values())]
                     for r in peer["results"]]))
        frames = [f"{r['scene']} {r['hpcmpm_output_ms_per_frame']:.2f} ms"
                  for r in peer["results"] if "hpcmpm_output_ms_per_frame" in r]
        if frames:
            print("\nOutput (not part of the step; the peer writes nothing): one frame, serial "
                  "HDF5, " + ", ".join(frames) + ".")
        print()
    ceiling = load(folder, "ceiling.json")
    if ceiling:
        print("### Ceiling: hpcmpm vs a fused numba MLS-MPM step\n")
        print(machine_line(ceiling) + "\n")
        print(table(
            ["scene", "particles", "ceiling ms/step min / median", "hpcmpm ms/step min / median",
             "hpcmpm / ceiling (min), range over launches", "(median), range"],
            [[r["scene"], r["particles"],
              f"{r['ceiling']['ms_per_step_min']:.3f} / {r['ceiling']['ms_per_step_median']:.3f}",
              f"{r['hpcmpm']['ms_per_step_min']:.3f} / {r['hpcmpm']['ms_per_step_median']:.3f}",
              ratio_range(r, "ratio_hpcmpm_over_ceiling_min"),
              ratio_range(r, "ratio_hpcmpm_over_ceiling_median")]
             for r in ceiling["results"]]))
        print()
    par = load(folder, "parallel.json")
    if par:
        print(f"### Parallel: scene {par['scene']}, {par['particles']} particles\n")
        print(machine_line(par) + "\n")
        print(table(["run", "ms/step min", "ms/step median", "M particle-steps/s (median)"],
                    [[k, v["ms_per_step_min"], v["ms_per_step_median"],
                      v["particle_steps_per_s_median"] / 1e6] for k, v in par["runs"].items()]))
        print()
        for code, e in par["efficiency"].items():
            rounds = e.get("efficiency_median_launches", [])
            spread = (f"; per round {min(rounds):.3f}-{max(rounds):.3f} over {len(rounds)} "
                      f"rounds of separate launches" if rounds else "")
            print(f"- {code}: efficiency t1/(2 t2) = {e['efficiency_median']:.3f} (medians), "
                  f"{e['efficiency_min']:.3f} (minima){spread}")
        for k in ("hpcmpm_1", "hpcmpm_2"):
            ph = par["runs"].get(k, {}).get("phases_max_over_ranks_s")
            if ph:
                steps = par["steps_per_rep"] * par["runs"][k]["reps"] / par["rounds"]
                print(f"- {k} phases (ms/step, slowest rank, last launch): " + ", ".join(
                    f"{n} {1e3 * s / steps:.2f}" for n, s in ph.items()))
        print()
    mem = load(folder, "memory.json")
    if mem:
        print("### Memory per particle\n")
        print(machine_line(mem) + "\n")
        print(table(["case", "particles", "fields B/particle", "peak RSS B/particle",
                     "grid block MiB"],
                    [[r["case"], r["particles"], r["nbytes_per_particle"],
                      r["rss_bytes_per_particle"], r["grid_block_bytes"] / 2**20]
                     for r in mem["results"]]))
        print()
    start = load(folder, "startup.json")
    if start:
        print("### Start-up: process start to the end of the first step\n")
        print(machine_line(start) + "\n")
        print(table(["scene", "cold s", "(imports done)", "(scene built)", "warm s",
                     "(imports done)", "(scene built)"],
                    [[r["scene"], r["cold"]["to_first_step_s"], r["cold"]["imported"],
                      r["cold"]["built"], r["warm_best"]["to_first_step_s"],
                      r["warm_best"]["imported"], r["warm_best"]["built"]]
                     for r in start["results"]]))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())

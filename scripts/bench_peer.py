"""Throughput against a peer: hpcmpm and Taichi's MLS-MPM (CPU backend, float64, one thread)
on the same scenes, in one process, repetitions alternating A (hpcmpm), B (Taichi), A, B, ...

Both codes get the same particles (positions, velocities, mass, volume), the same grid spacing,
the same fixed dt and the same walls (scripts/bench_common.py describes the scenes); both
step from the same state in every repetition, since each repetition advances both by the same
number of steps. The peer is scripts/peer/mls_mpm.py (after Taichi's mpm88/mpm99/mpm3d). After
the run, the largest distance between the two codes' particle positions (in cells) is reported
as a check that they did the same work.

Reports ms/step (min and median over repetitions), particle-steps/s, the ratio hpcmpm/peer
(throughput, > 1 means hpcmpm is faster), and hpcmpm's phase times. Writes
bench_results/peer.json.

Each scene runs in a process of its own, ``--launches`` times (default 3): one Taichi runtime
never holds several scenes, and the ratio is reported as its range over the launches (the
peer's time moved by 45 % between launches of the same command; BENCHMARKS.md). Every launch
records the machine: CPU model and flags, usable cores, load average, thread settings.

    python scripts/bench_peer.py --scene all --reps 7 --launches 3
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "peer"))
import bench_common as bc  # noqa: E402

DEFAULT_STEPS = {"a": 200, "a_fc": 200, "b": 10}


def make_peer(s: bc.BenchScene):
    import mls_mpm

    return mls_mpm.MLSMPM(s.dim, s.n_grid, s.dt, s.x0, s.v0, s.p_vol, s.rho, s.material,
                          float(s.params["E"]), float(s.params.get("nu", 0.0)),
                          gravity=s.gravity, bound=s.bound)


def bench_scene(key: str, steps: int, reps: int, smoke: bool, warmup: int) -> dict:
    import mls_mpm

    s = bc.make_scene(key, smoke)
    sim = bc.build_hpcmpm(s)
    peer = make_peer(s)

    def run_hpcmpm(k: int) -> None:
        for _ in range(k):
            sim.step(s.dt)

    def run_peer(k: int) -> None:
        for _ in range(k):
            peer.substep()
        mls_mpm.sync()

    run_hpcmpm(warmup)  # compiles (numba) / JITs (Taichi)
    run_peer(warmup)
    sim.timers.reset()
    t_hp, t_peer = [], []
    for _ in range(reps):
        t_hp.append(bc.timed(run_hpcmpm, steps))
        t_peer.append(bc.timed(run_peer, steps))
    hp, pe = bc.summarize(t_hp, steps, s.n), bc.summarize(t_peer, steps, s.n)
    output_ms = bc.frame_output_ms(sim)
    p = sim.particles
    x_hp = np.empty_like(s.x0)
    x_hp[p["id"]] = p["x"]
    x_peer = peer.positions()
    if not (np.all(np.isfinite(x_hp)) and np.all(np.isfinite(x_peer))):
        raise RuntimeError(f"scene {key}: non-finite positions")
    return {
        "scene": key, "title": s.title, "particles": s.n, "grid": s.n_grid, "dim": s.dim,
        "dt": s.dt, "material": s.material, "params": s.params,
        "steps_total": warmup + reps * steps,
        "hpcmpm": hp, "peer": pe,
        "ratio_hpcmpm_over_peer_min": pe["ms_per_step_min"] / hp["ms_per_step_min"],
        "ratio_hpcmpm_over_peer_median": pe["ms_per_step_median"] / hp["ms_per_step_median"],
        "hpcmpm_phases_ms_per_step": bc.phase_ms(sim.timers, steps * reps),
        "hpcmpm_output_ms_per_frame": output_ms,
        "max_position_difference_cells": float(np.abs(x_hp - x_peer).max() * s.n_grid),
        # OS threads of this process after the run (Taichi's workers included): the thread
        # settings the timing was taken under.
        "process_threads": len(os.listdir("/proc/self/task")) if os.path.isdir(
            "/proc/self/task") else None,
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
    }


def passthrough(args) -> list[str]:
    out = ["--reps", str(args.reps), "--warmup", str(args.warmup)]
    out += ["--steps", str(args.steps)] if args.steps else []
    out += ["--smoke"] if args.smoke else []
    out += ["--taichi-threads", str(args.taichi_threads)]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="all", choices=["a", "a_fc", "b", "all"])
    ap.add_argument("--steps", type=int, default=None,
                    help="steps per repetition (default: a, a_fc 200; b 10; smoke 5)")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--smoke", action="store_true", help="tiny scenes (tests)")
    ap.add_argument("--taichi-threads", type=int, default=1,
                    help="Taichi's cpu_max_num_threads (default 1: one core each)")
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    bc.add_launch_arguments(ap)
    args = ap.parse_args(argv)
    try:
        import mls_mpm
    except ImportError as exc:
        print(f"taichi not installed (pip install -e '.[bench]'): {exc}", file=sys.stderr)
        return 3
    keys = ["a", "a_fc", "b"] if args.scene == "all" else [args.scene]
    if args.in_process:
        mls_mpm.init(threads=args.taichi_threads)
        os.environ.setdefault("NUMBA_NUM_THREADS", "1")
        results = []
        for key in keys:
            steps = args.steps or (5 if args.smoke else DEFAULT_STEPS[key])
            results.append(bench_scene(key, steps, args.reps, args.smoke, args.warmup))
        doc = {"machine": bc.machine_info(), "results": results}
    else:
        doc = bc.run_launches(Path(__file__), args, keys, "peer.json", passthrough(args))
    results = doc["results"]
    bc.print_table(
        ["scene", "particles", "hpcmpm ms/step min", "med", "Mpart-steps/s",
         "peer ms/step min", "med", "Mpart-steps/s", "hpcmpm/peer", "max |dx| cells"],
        [[r["scene"], r["particles"], r["hpcmpm"]["ms_per_step_min"],
          r["hpcmpm"]["ms_per_step_median"], r["hpcmpm"]["particle_steps_per_s_best"] / 1e6,
          r["peer"]["ms_per_step_min"], r["peer"]["ms_per_step_median"],
          r["peer"]["particle_steps_per_s_best"] / 1e6, r["ratio_hpcmpm_over_peer_min"],
          r["max_position_difference_cells"]] for r in results])
    for r in results:
        if "launches" in r:
            print(f"{r['scene']}: hpcmpm/peer over separate launches: min "
                  f"{bc.range_text(r, 'ratio_hpcmpm_over_peer_min')}, median "
                  f"{bc.range_text(r, 'ratio_hpcmpm_over_peer_median')}; peer ms/step (min) "
                  + ", ".join(f"{x['peer']['ms_per_step_min']:.3f}" for x in r["launches"]))
        print(f"{r['scene']}: hpcmpm phases (ms/step): " + ", ".join(
            f"{k} {v:.3f}" for k, v in r["hpcmpm_phases_ms_per_step"].items())
            + f"; output {r['hpcmpm_output_ms_per_frame']:.2f} ms/frame")
    path = bc.write_json("peer.json", doc, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

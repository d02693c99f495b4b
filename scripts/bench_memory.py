"""Memory per particle for 2D/3D elastic and plastic (snow) scenes.

Two numbers per scene:

- ``ParticleSet.nbytes_per_particle()``: the bytes of every per-particle field hpcmpm declares
  for that scene (id, group, x, v, mass, vol0, F, tau, C, and the material's own fields).
- peak RSS per particle, measured in a fresh process: import hpcmpm and compile every kernel on
  a tiny copy of the scene, reset the kernel's peak-RSS mark (``echo 5 >
  /proc/self/clear_refs``, Linux), read ``ru_maxrss`` right after the reset as the baseline
  (the resident size then), build the full scene and run ``--steps`` steps, then read the
  peak with ``resource.getrusage(RUSAGE_SELF).ru_maxrss``. ``(peak - baseline) / n`` counts
  everything the run holds per particle: the fields, the spare capacity of the arrays, the
  sort's scratch copies and keys, the grid block (shared by the particles), and the scene's
  input arrays (the benchmark's own x0/v0, 2 d doubles per particle, included and stated).

Scenes: 2D = scene a's layout with ``--n2d`` particles (default 262144, grid grown with it),
3D = scene b (262144 particles on 64^3); fluid = weakly compressible (2D only: it carries J
instead of F), elastic = fixed corotated, plastic = snow. Writes
bench_results/memory.json. The target is <= 300 B/particle for 3D elastic.

    python scripts/bench_memory.py
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_common as bc  # noqa: E402

MARK = "BENCH_RESULT "
CASES = {  # name: (scene key, material)
    "2d_fluid": ("a", bc.FLUID),
    "2d_elastic": ("a_fc", bc.COROTATED),
    "2d_snow": ("a_fc", bc.SNOW),
    "3d_elastic": ("b", bc.COROTATED),
    "3d_snow": ("b", bc.SNOW),
}


def vm_rss_kib() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def worker(case: str, steps: int, smoke: bool, n2d: int) -> None:
    key, material = CASES[case]
    n2 = None if smoke else n2d
    tiny = bc.make_scene(key, smoke=True, material=material)
    sim = bc.build_hpcmpm(tiny)
    for _ in range(2):
        sim.step(tiny.dt)  # compile every kernel this scene uses before the baseline
    del sim, tiny
    s = bc.make_scene(key, smoke=smoke, material=material, n2d=n2 if key != "b" else None)
    peak_reset = reset_peak()
    # The baseline in the same accounting as the peak (ru_maxrss right after the reset is the
    # resident size then); VmRSS is recorded too.
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    base_vm = vm_rss_kib()
    sim = bc.build_hpcmpm(s)
    for _ in range(steps):
        sim.step(s.dt)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    p = sim.particles
    out = {"case": case, "scene": key, "material": material, "dim": s.dim, "particles": s.n,
           "grid": s.n_grid, "steps": steps,
           "fields": {name: p[name].dtype.itemsize * (p[name].size // max(p.n, 1))
                      for name in p.field_names()},
           "nbytes_per_particle": p.nbytes_per_particle(),
           "capacity": p.capacity, "grid_block_bytes": sim.grid.nbytes(),
           "baseline_rss_kib": base, "baseline_vmrss_kib": base_vm, "peak_rss_kib": peak, "peak_reset": peak_reset,
           "rss_bytes_per_particle": (peak - base) * 1024.0 / s.n,
           "input_bytes_per_particle": 2 * s.dim * 8}
    print(MARK + json.dumps(out), flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--n2d", type=int, default=262144, help="particles in the 2D scenes")
    ap.add_argument("--smoke", action="store_true", help="tiny scenes (tests)")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    steps = args.steps or (2 if args.smoke else 5)
    if args.worker:
        worker(args.worker, steps, args.smoke, args.n2d)
        return 0
    results = []
    for case in args.cases:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", case,
               "--steps", str(steps), "--n2d", str(args.n2d)] + (["--smoke"] if args.smoke else [])
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
        lines = [ln for ln in out.stdout.splitlines() if ln.startswith(MARK)]
        if not lines:
            raise SystemExit(f"{case}: no result (exit {out.returncode}):\n{out.stderr[-3000:]}")
        results.append(json.loads(lines[-1][len(MARK):]))
    bc.print_table(
        ["case", "particles", "fields B/particle", "peak RSS B/particle", "grid MiB"],
        [[r["case"], r["particles"], r["nbytes_per_particle"], r["rss_bytes_per_particle"],
          r["grid_block_bytes"] / 2**20] for r in results])
    for r in results:
        print(f"{r['case']}: " + ", ".join(f"{k} {v}" for k, v in r["fields"].items()))
    path = bc.write_json("memory.json", {"machine": bc.machine_info(), "results": results,
                                         "method": __doc__.split("\n\n")[1]}, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

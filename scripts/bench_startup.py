"""Start-up time: from process start to the end of the first step, cold and warm.

Cold: a new, empty NUMBA_CACHE_DIR, so every kernel the scene uses is compiled. Warm: the same
cache directory again, so numba loads the compiled kernels from it. Each run is a fresh Python
process that imports hpcmpm, builds the scene (scripts/bench_common.py) and takes one step;
the time is taken by this (parent) script from just before it starts the process to the moment
the child reports the first step done (the child's own milestones, relative to the parent's
start, are recorded too: imports done, scene built). Writes bench_results/startup.json.

    python scripts/bench_startup.py --scenes a b --warm-runs 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_common as bc  # noqa: E402

MARK = "BENCH_RESULT "


def child(scene: str, smoke: bool) -> None:
    marks = {}
    import hpcmpm.simulation  # noqa: F401  (the package and its kernels' modules)

    marks["imported"] = time.time()
    s = bc.make_scene(scene, smoke)
    sim = bc.build_hpcmpm(s)
    marks["built"] = time.time()
    sim.step(s.dt)
    marks["first_step"] = time.time()
    sim.step(s.dt)
    marks["second_step"] = time.time()
    print(MARK + json.dumps(marks), flush=True)


def run_once(scene: str, smoke: bool, cache_dir: str, timeout: float) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, NUMBA_NUM_THREADS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", scene] + \
        (["--smoke"] if smoke else [])
    start = time.time()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith(MARK)]
    if not lines:
        raise SystemExit(f"startup run failed (exit {out.returncode}):\n{out.stderr[-3000:]}")
    marks = json.loads(lines[-1][len(MARK):])
    rel = {k: v - start for k, v in marks.items()}
    rel["to_first_step_s"] = rel.pop("first_step")
    rel["second_step_s"] = rel.pop("second_step") - rel["to_first_step_s"]
    return rel


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["a", "b"], choices=["a", "a_fc", "b"])
    ap.add_argument("--warm-runs", type=int, default=3)
    ap.add_argument("--smoke", action="store_true", help="tiny scenes (tests)")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.smoke)
        return 0
    results = []
    for scene in args.scenes:
        with tempfile.TemporaryDirectory(prefix="hpcmpm-numba-") as cache:
            cold = run_once(scene, args.smoke, cache, args.timeout)
            warm = [run_once(scene, args.smoke, cache, args.timeout)
                    for _ in range(args.warm_runs)]
        best = min(warm, key=lambda r: r["to_first_step_s"])
        results.append({"scene": scene, "cold": cold, "warm_runs": warm, "warm_best": best,
                        "cold_to_first_step_s": cold["to_first_step_s"],
                        "warm_to_first_step_s": best["to_first_step_s"]})
    bc.print_table(
        ["scene", "cold: to first step s", "(imports", "built)", "warm: to first step s",
         "(imports", "built)"],
        [[r["scene"], r["cold"]["to_first_step_s"], r["cold"]["imported"], r["cold"]["built"],
          r["warm_best"]["to_first_step_s"], r["warm_best"]["imported"],
          r["warm_best"]["built"]] for r in results])
    path = bc.write_json("startup.json", {"machine": bc.machine_info(), "results": results},
                         args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

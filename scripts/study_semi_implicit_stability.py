"""The largest multiple of the explicit time step at which the semi-implicit integrator stays
stable (issue 9, target >= 10x), on sponge_twist_ob_3d and pie_2d.

The explicit step is min(cfl dx / (c + |v|max), rho dx^2 / (2 d mu_N)) over the materials at the
start (c the P-wave speed; the thrown pie's |v| = 3). For each multiple k, from the largest
down, the scene runs with a fixed dt = k dt_explicit over a window that holds its hard part:
the twist from t = 0 to 0.3 (sponge), the impact from t = 0.1 to 0.25 (pie; the flight before
it is run once at the advective dt and restarted from memory). Stable: no instability error,
no solver failure, and |v|max stays below 10x the fastest boundary or initial speed.

    python scripts/study_semi_implicit_stability.py
    python scripts/study_semi_implicit_stability.py --scene pie_2d --multiples 1000 300 100
    python scripts/study_semi_implicit_stability.py --smoke

Writes bench_results/study_semi_implicit_stability.json.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hpcmpm.errors import InstabilityError  # noqa: E402
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain  # noqa: E402
from hpcmpm.scene import load_scene  # noqa: E402
from hpcmpm.simulation import Simulation  # noqa: E402

# scene: (window start, window end, speed scale for the blow-up check)
WINDOWS = {"sponge_twist_ob_3d": (0.0, 0.3, 3.14159 * 0.2), "pie_2d": (0.1, 0.25, 3.0)}
MULTIPLES = (3000, 1000, 300, 100, 30, 10)


def explicit_dt(sim, speed: float) -> float:
    dt = sim.scene.cfl * sim.dx / (max(m.wave_speed() for m in sim.materials) + speed)
    return min([dt] + [m.dt_limit(sim.dx) for m in sim.materials])


def build(name, overrides):
    scene = load_scene(str(ROOT / "inputs" / f"{name}.toml"), list(overrides))
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    return sim


def advance(sim, end: float, speed_limit: float) -> float:
    """Run to ``end`` (fixed dt from the scene); returns the largest |v| seen."""
    top = [0.0]

    def observe(s):
        top[0] = max(top[0], float(np.abs(s.particles["v"]).max()))
        if not top[0] < speed_limit:
            raise InstabilityError(f"|v| = {top[0]:.3g} exceeds {speed_limit:.3g}")

    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=end, quiet=True),
           observer=observe).run()
    return top[0]


def study(name: str, multiples, extra=(), window=None) -> dict:
    start, end, speed = window or WINDOWS[name]
    base = build(name, extra)
    dt_e = explicit_dt(base, speed)
    if start > 0:  # the approach, once, at the advective dt
        advance(base, start, 10 * speed)
    rows = {}
    for k in multiples:
        # Frames only at the window's end: a frame time would clip the fixed dt.
        sim = build(name, [*extra, f"simulation.dt={k * dt_e}", f"output.every={end}"])
        sim.particles = copy.deepcopy(base.particles)
        sim.time, sim.step_index = base.time, base.step_index
        sim.request_sort()
        t0 = time.perf_counter()
        try:
            vmax = advance(sim, end, 10 * speed)
            stable, why = True, ""
        except InstabilityError as exc:
            vmax, stable, why = math.nan, False, str(exc).splitlines()[0][:160]
        rows[k] = {"dt": k * dt_e, "stable": stable, "steps": sim.step_index - base.step_index,
                   "vmax": vmax, "wall_s": time.perf_counter() - t0, "reason": why}
        print(f"{name}: {k}x explicit (dt = {k * dt_e:.3g}): "
              f"{'stable' if stable else 'UNSTABLE: ' + why}", flush=True)
    stable = [k for k in multiples if rows[k]["stable"]]
    return {"explicit_dt": dt_e, "window": [start, end], "runs": {str(k): v for k, v in
                                                                    rows.items()},
            "largest_stable_multiple": max(stable) if stable else 0}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=sorted(WINDOWS), action="append")
    parser.add_argument("--multiples", type=float, nargs="+", default=MULTIPLES)
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args(argv)
    results = {}
    for name in args.scene or sorted(WINDOWS):
        if args.smoke:
            extra = ["simulation.dx=0.05"] if name.endswith("3d") else []
            s, e, v = WINDOWS[name]
            results[name] = study(name, (300,), extra, (s, s + 0.02, v))
        else:
            results[name] = study(name, args.multiples)
    out = ROOT / "bench_results"
    out.mkdir(exist_ok=True)
    suffix = "_smoke" if args.smoke else ""
    (out / f"study_semi_implicit_stability{suffix}.json").write_text(
        json.dumps(results, indent=1, default=float))
    return results


if __name__ == "__main__":
    main()

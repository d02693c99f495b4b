"""000 Fig. 5.4: a blob of volume-preserving Oldroyd-B material dropped on the floor settles
lower the smaller its Weissenberg number (the faster b_E relaxes to I, the more plastic the
flow). Semi-implicit, 2D: a disk of radius 0.1 falls from rest at height 0.35 onto a sticky
floor (mu 20, lambda 200, mu_N 0.01, rho 1, g 9.81; Maxwell viscosity mu Wi from 200 at
Wi = 10 down to 0.2 at Wi = 0.01).

    python scripts/study_blob_weissenberg.py              # Wi = 10, 1, 0.1, 0.01; dx = 1/64
    python scripts/study_blob_weissenberg.py --smoke      # dx = 1/32, shorter

The settled height is the 99th percentile of the particles' height at the end (robust to a
stray particle). Writes bench_results/study_blob_weissenberg.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hpcmpm.runner import simulate  # noqa: E402
from hpcmpm.scene import parse_scene  # noqa: E402

WEISSENBERGS = (10.0, 1.0, 0.1, 0.01)

SCENE = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 0.5] }}
dx = {dx}
particles_per_cell = 2
kernel = "quadratic"
transfer = "apic"
integrator = "semi_implicit"
cfl = 0.4
end_time = {end}
gravity = [0.0, -9.81]

[solver]
tolerance = 1e-6

[output]
every = {end}

[[materials]]
name = "blob"
type = "oldroyd_b"
density = 1.0
mu = 20.0
lambda = 200.0
viscosity = 0.01
relaxation_time = {wi}

[[bodies]]
name = "blob"
material = "blob"
shape = "sphere"
center = [0.5, 0.35]
radius = 0.1

[walls]
default = "sticky"
"""


def settled_height(wi: float, dx: float, end: float) -> tuple[float, int, float]:
    scene = parse_scene(SCENE.format(dx=dx, end=end, wi=wi))
    start = time.perf_counter()
    sim = simulate(scene)
    wall = time.perf_counter() - start
    return float(np.percentile(sim.particles["x"][:, 1], 99)), sim.step_index, wall


def study(weissenbergs=WEISSENBERGS, dx=1 / 64, end=1.5) -> dict:
    rows = {}
    for wi in weissenbergs:
        height, steps, wall = settled_height(wi, dx, end)
        rows[wi] = {"height": height, "steps": steps, "wall_s": wall}
        print(f"Wi = {wi:g}: settled height {height:.4f} ({steps} steps, {wall:.1f} s)",
              flush=True)
    heights = [rows[wi]["height"] for wi in weissenbergs]
    monotone = all(a > b for a, b in zip(heights, heights[1:]))
    print(f"heights fall monotonically as Wi goes {weissenbergs[0]:g} -> "
          f"{weissenbergs[-1]:g}: {monotone}")
    return {"dx": dx, "end_time": end, "runs": {str(k): v for k, v in rows.items()},
            "monotone": monotone}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args(argv)
    result = study((10.0, 0.1, 0.01), 1 / 32, 0.8) if args.smoke else study()
    out = ROOT / "bench_results"
    out.mkdir(exist_ok=True)
    name = "study_blob_weissenberg" + ("_smoke" if args.smoke else "") + ".json"
    (out / name).write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()

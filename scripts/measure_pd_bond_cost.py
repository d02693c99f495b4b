"""Measure c_b, the load-balance cost of one active half-bond in units of an MPM particle
(hpcmpm/pd/load.py): CPU time per step of the same block of particles as an MPM body
(neo-Hookean) and as an off-grid PD body (one model), on one core.

    cost per PD particle-step / cost per MPM particle-step = 1 + c_b * (half-bonds per particle)

so c_b = (t_pd / t_mpm - 1) / b with b the mean active half-bonds per PD particle. CPU time
(`time.process_time`) of `steps` steps after a warm-up, the smallest of `repeats` runs (the
machine is shared: the minimum is the run least disturbed by other processes).

Usage: python scripts/measure_pd_bond_cost.py [--dim 2] [--model pmb] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

SCENE = """
[simulation]
dim = {dim}
domain = {{ lower = {lo}, upper = {hi} }}
dx = 0.02
particles_per_cell = 2
transfer = "apic"
end_time = 1.0
dt = {dt}

[[materials]]
name = "body"
{material}
density = 1000.0
E = 1.0e6
nu = 0.25

[[materials]]
name = "neo"
type = "neo_hookean"
density = 1000.0
E = 1.0e6
nu = 0.25

[[bodies]]
material = "body"
shape = "box"
lower = {blo}
upper = {bhi}
"""


def scene_text(dim: int, material: str, cells: int) -> str:
    side = cells * 0.02
    lo, hi = [0.0] * dim, [side + 0.4] * dim
    blo, bhi = [0.2] * dim, [0.2 + side] * dim
    return SCENE.format(dim=dim, lo=lo, hi=hi, blo=blo, bhi=bhi, material=material, dt=2e-5)


def cpu_per_step(text: str, steps: int, repeats: int) -> tuple[float, int, float]:
    """(least CPU seconds per step over the repeats, particles, mean half-bonds each)."""
    best, n, bonds = np.inf, 0, 0.0
    for _ in range(repeats):
        scene = parse_scene(text, path="cost.toml")
        sim = Simulation(scene, make_domain(scene))
        initial_particles(sim)
        p = sim.particles
        p["v"][:] = 0.01 * (p["x"] - p["x"].mean(axis=0))
        for _ in range(3):                  # warm-up: compilation, families, first sort
            sim.step(2e-5)
        start = time.process_time()
        for _ in range(steps):
            sim.step(2e-5)
        best = min(best, (time.process_time() - start) / steps)
        n = p.n
        if sim.extensions:
            bonds = float(sim.extensions[0].bonds.intact_counts().mean())
    return best, n, bonds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dim", type=int, default=2)
    ap.add_argument("--model", default="pmb", choices=("pmb", "lps", "correspondence"))
    ap.add_argument("--cells", type=int, default=0, help="block side in cells (default 2D 40, "
                    "3D 12)")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cells = args.cells or (40 if args.dim == 2 else 12)
    mpm = 'type = "neo_hookean"'
    pd = f'type = "peridynamic"\nmodel = "{args.model}"\nintegration = "pd"' + (
        '\nstress_material = "neo"' if args.model == "correspondence" else "")
    t_mpm, n, _ = cpu_per_step(scene_text(args.dim, mpm, cells), args.steps, args.repeats)
    t_pd, _, bonds = cpu_per_step(scene_text(args.dim, pd, cells), args.steps, args.repeats)
    c_b = (t_pd / t_mpm - 1.0) / bonds
    print(f"dim {args.dim}, model {args.model}, {n} particles, {bonds:.1f} half-bonds each: "
          f"MPM {t_mpm / n * 1e9:.0f} ns, PD {t_pd / n * 1e9:.0f} ns per particle-step "
          f"(CPU, least of {args.repeats}); c_b = {c_b:.4f}")


if __name__ == "__main__":
    main()

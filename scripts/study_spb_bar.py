"""SPB-MPM stretched bar (inputs/spb_stretched_bar_2d.toml) at several grid spacings: the
elongation at which it separates, and the stress at its first conversion.

003 §6.4.2 claims the SPB-MPM fracture is barely affected by the grid (Fig. 6.5). Here each dx
keeps the material's sigma_c (G_EE = l0 sigma_c^2 with l0 = delta = 3.015 spacings, so G_EE
scales with dx) and G_c; the separation time is when the velocity field gets a step across the
bar (`separated`), and the elongation is 2 v t / L there (single rank, the rank count only
changes round-off).

Measured at a13e8da (1 rank): elongation at separation 0.030 (dx = 0.028), 0.062 (0.014),
0.081 (0.007): not grid independent. The horizon is 3.015 spacings, so delta shrinks with dx,
and a bond's break strain under eq. 6.11-6.12 grows as delta^(-1/2) (W ~ e^2 |X|^2 / delta^4
against W_c ~ G_c / delta^3), as the critical stretch of any PD model with a fixed G_c does.
With the horizon fixed in length (``--fixed-horizon``: delta = 3.015 x 0.014 = 0.0422 at every
dx, so 3.015, 6.03 and 12.06 spacings) the elongation is 0.0304, 0.0331, 0.0313: grid
independent, as 003 claims, once delta is held fixed (2026-11-30, main).
Stress at the first conversion (the converting particles' mean, now): -8.7 %, -5.2 %, -5.4 %
of sigma_c, the stress waves of the sudden pull (2 rho c v = 15 % of sigma_c at 0.3 m/s);
at their largest stress so far it is sigma_c (tests/verification/test_spb_coupled.py).

    python scripts/study_spb_bar.py                 # dx = 0.028, 0.014, 0.007 (minutes)
    python scripts/study_spb_bar.py --smoke         # dx = 0.028 only (the CI smoke test)
    python scripts/study_spb_bar.py --fixed-horizon  # delta fixed at 3.015 x 0.014 = 0.0422
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
from hpcmpm.parallel import Communicator
from hpcmpm.scene import load_scene
from hpcmpm.simulation import Simulation

SCENE = "inputs/spb_stretched_bar_2d.toml"
SIGMA_C = 400.0
PULL = 0.3          # m/s per end (the scene's prescribed velocity)
LENGTH = 0.56       # the bar's length at t = 0


def separated(sim) -> bool:
    """A crack across the bar: some row of particles (rows of one cell in the reference
    configuration) has at least 90 % of its particles with damage >= 0.5. (A gap in the
    positions does not work: the freed band keeps flowing on the grid like a stress-free
    material, spreading its particles; nor does a step in the velocity: the edge of a fresh
    PD patch gets velocity kicks before anything breaks.)"""
    p = sim.particles
    rows = np.floor(p["x0"][:, 1] / sim.dx).astype(np.int64)
    rows -= rows.min()
    counts = np.bincount(rows)
    cracked = np.bincount(rows, weights=(p["damage"] >= 0.5).astype(np.float64))
    return bool(np.max(cracked[counts > 0] / counts[counts > 0]) >= 0.9)


def run(dx: float, end_time: float, horizon: float | None = None) -> dict:
    """``horizon``: delta in length units, fixed across dx (the horizon key then grows as
    delta / spacing); None: 3.015 spacings (the default, delta shrinking with dx)."""
    ppc = 2
    spacing = dx / ppc
    spacings = 3.015 if horizon is None else horizon / spacing
    l0 = spacings * spacing
    scene = load_scene(SCENE, [f"simulation.dx={dx}", f"simulation.end_time={end_time}",
                               f"materials.0.failure.grid_energy={l0 * SIGMA_C ** 2}",
                               f"materials.0.failure.horizon={spacings}"])
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    out: dict = {"dx": dx, "n": sim.particles.n}

    def observe(sim):
        ext = sim.extensions[0]
        if "t_convert" not in out and ext.pd_global:
            p = sim.particles
            sigma = sim.kirchhoff_stress()[:, 1, 1] / np.linalg.det(p["F"])
            out["t_convert"] = sim.time
            out["sigma_convert"] = float(sigma[p["model"] == 1].mean())
        if "t_separate" not in out and ext.broken and sim.step_index % 5 == 0 and \
                separated(sim):
            out["t_separate"] = sim.time
            out["elongation"] = 2 * PULL * sim.time / LENGTH
            raise StopIteration

    start = time.perf_counter()
    try:
        # A scratch folder: the runner writes a checkpoint there only on SIGTERM.
        Runner(sim, None, RunOptions(out_dir=Path(tempfile.mkdtemp()), end_time=end_time,
                                     quiet=True), observer=observe).run()
    except StopIteration:
        pass
    ext = sim.extensions[0]
    out.update(wall=time.perf_counter() - start, pd=ext.pd_global, broken=ext.broken,
               steps=sim.step_index)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="coarsest dx only, short run")
    ap.add_argument("--fixed-horizon", action="store_true",
                    help="delta = 3.015 spacings of the coarsest dx at every dx")
    ap.add_argument("--dx", type=float, nargs="+", help="grid spacings (default 0.028 0.014 "
                    "0.007)")
    args = ap.parse_args()
    spacings = [0.028] if args.smoke else (args.dx or [0.028, 0.014, 0.007])
    end = 0.05 if args.smoke else 0.15
    horizon = 3.015 * max(spacings) / 2 if args.fixed_horizon else None
    for dx in spacings:
        r = run(dx, end, horizon)
        conv = (f"first conversion at t = {r['t_convert']:.4f}, sigma = "
                f"{r['sigma_convert']:.1f} ({r['sigma_convert'] / SIGMA_C - 1:+.1%})"
                if "t_convert" in r else "no conversion")
        sep = (f"separates at t = {r['t_separate']:.4f}, elongation {r['elongation']:.4f}"
               if "t_separate" in r else "not separated")
        print(f"dx = {dx}: {r['n']} particles, {conv}; {sep}; PD {r['pd']}, half-bonds broken "
              f"{r['broken']}, {r['steps']} steps in {r['wall']:.0f} s", flush=True)


if __name__ == "__main__":
    main()

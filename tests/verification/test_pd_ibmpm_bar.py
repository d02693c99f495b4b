"""Integral-based MPM (003 ch. 5) on the round-1 bar: the correspondence bond force through
the grid gives the first-mode period T = 4L/c = 10 (inputs/ibmpm_bar_2d.toml) within 2 %,
the error falling with dx at a fixed horizon in spacings."""

import numpy as np

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene

L, PERIOD = 25.0, 10.0


def period(cells: int) -> float:
    scene = load_scene("inputs/ibmpm_bar_2d.toml",
                       [f"simulation.dx={L / cells}", "simulation.end_time=8.0"])
    history = []

    def observe(sim):
        p = sim.particles
        history.append((sim.time, (p["mass"] * p["v"][:, 0]).sum() / p["mass"].sum()))

    simulate(scene, observer=observe)
    t, v = np.array(history).T
    # Zero crossings of the centre-of-mass velocity at T/4 and 3T/4 (linear interpolation).
    i = np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))[:2]
    zeros = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    return 2 * (zeros[1] - zeros[0])


def test_ibmpm_bar_period():
    errors = [abs(period(c) - PERIOD) / PERIOD for c in (25, 50)]
    print(f"integral-based MPM bar period errors at 25, 50 cells: {errors}")
    # The 2 %; measured 1.15 % and 0.60 % (and 0.27 % at 100 cells, left out for
    # time). The error comes from the PD layer of width ~delta at the free end: first order.
    assert errors[0] < 2e-2 and errors[1] < 2e-2
    assert errors[1] < 0.7 * errors[0]

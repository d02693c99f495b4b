"""Prescribed rigid motion of off-grid PD particles (``integration = "pd"``, 003 Alg. 2).

A ``[[prescribed]]`` set clamps MPM particles through the grid nodes of their support
(hpcmpm/boundaries/prescribed.py); PD particles off the grid have no nodes, so their set's
rigid velocity v + omega x (x - c(t)) is imposed on the particles themselves after the bond
forces, before the position update (the velocity boundary condition of PD codes, e.g. the
Kalthoff-Winkler impactor, Silling 2003).
"""

from __future__ import annotations

import numpy as np


def impose_prescribed_velocity(sim, start: int, stop: int, v: np.ndarray) -> None:
    """Overwrite ``v`` (the rows [start, stop)) of particles in a prescribed set."""
    if not getattr(sim, "prescribed", None) or "prescribed" not in sim.particles:
        return
    tags = sim.particles["prescribed"][start:stop]
    x = sim.particles["x"][start:stop]
    dim = sim.dim
    for clamp in sim.prescribed:
        rows = np.flatnonzero(tags == clamp.index)
        if len(rows) == 0:
            continue
        r = np.zeros((len(rows), 3))
        r[:, :dim] = x[rows] - clamp.centre(sim.time)[:dim]
        v[rows] = (clamp.velocity + np.cross(clamp.omega, r))[:, :dim]

"""The boundary conditions of particles moved off the grid (003 Alg. 2): off-grid PD bodies
(``integration = "pd"``) and the crack planes' two-time integration (particles with a broken
bond, crack_planes.py).

Walls and colliders act on such particles one by one (contact.py). A ``[[prescribed]]`` set
clamps MPM particles through the grid nodes of their support
(hpcmpm/boundaries/prescribed.py); particles off the grid have no nodes, so their set's rigid
velocity v + omega x (x - c(t)) is imposed on the particles themselves after the bond forces,
before the position update (the velocity boundary condition of PD codes, e.g. the
Kalthoff-Winkler impactor, Silling 2003).
"""

from __future__ import annotations

import numpy as np

from .contact import ParticleColliders, ParticleWalls


class OffGridBoundaries:
    """The scene's walls, colliders and prescribed sets as they act on particles that move
    off the grid, in the grid's order: walls, then colliders, then the prescribed velocity,
    which wins."""

    def __init__(self, scene):
        self.walls = ParticleWalls(scene)
        self.colliders = ParticleColliders(scene)

    def apply(self, sim, rows, x: np.ndarray, v: np.ndarray, dt: float) -> None:
        """Act on ``v`` of the particles ``rows`` (a slice or an index array of the particle
        set; x and v hold their positions at the start of the step and their velocities, in
        that order), before the position update."""
        self.walls.apply(x, v, dt)
        self.colliders.apply(x, v, sim.time, dt)
        impose_prescribed_velocity(sim, rows, x, v)


def impose_prescribed_velocity(sim, rows, x: np.ndarray, v: np.ndarray) -> None:
    """Overwrite ``v`` of the particles ``rows`` (a slice or an index array; x, their
    positions, and v in that order) that belong to a prescribed set."""
    if not getattr(sim, "prescribed", None) or "prescribed" not in sim.particles:
        return
    tags = sim.particles["prescribed"][rows]
    dim = sim.dim
    for clamp in sim.prescribed:
        mine = np.flatnonzero(tags == clamp.index)
        if len(mine) == 0:
            continue
        r = np.zeros((len(mine), 3))
        r[:, :dim] = x[mine] - clamp.centre(sim.time)[:dim]
        v[mine] = (clamp.velocity + np.cross(clamp.omega, r))[:, :dim]

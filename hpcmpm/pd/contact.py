"""Walls and colliders for peridynamic particles off the grid (003 Alg. 2: colliders and
walls act per particle when the particles are not on the grid).

A particle whose position after the step, x + dt v, would lie beyond a face of the domain box
or inside an analytic collider (placed where it is at the end of the step) gets its velocity
projected against that face or relative to the collider's rigid velocity as a grid node would
(`boundaries.contact`: sticky, slip, separate with Coulomb friction; the colliders' own
`Collider.apply_to_particles`), before the position update; so a PD body stops at the
obstacle instead of passing it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..boundaries import make_colliders
from ..boundaries.contact import CONDITIONS, project


@njit(cache=True)
def walls_on_particles(x, v, dt, lo, hi, conditions, frictions, active):
    """Project v (n, d) in place for particles about to cross an active face; faces in the
    order x-, x+, y-, y+, (z-, z+). Returns the number of projections."""
    n, dim = x.shape
    hits = 0
    for p in range(n):
        for face in range(2 * dim):
            if not active[face]:
                continue
            axis = face // 2
            upper = face % 2 == 1
            y = x[p, axis] + dt * v[p, axis]
            if (upper and y <= hi[axis]) or (not upper and y >= lo[axis]):
                continue
            sign = -1.0 if upper else 1.0
            n0 = sign if axis == 0 else 0.0
            n1 = sign if axis == 1 else 0.0
            n2 = sign if axis == 2 else 0.0
            v2 = v[p, 2] if dim == 3 else 0.0
            r0, r1, r2 = project(v[p, 0], v[p, 1], v2, n0, n1, n2, conditions[face],
                                 frictions[face])
            v[p, 0] = r0
            v[p, 1] = r1
            if dim == 3:
                v[p, 2] = r2
            hits += 1
    return hits


class ParticleWalls:
    """The scene's walls as they act on off-grid particles (periodic faces excluded)."""

    def __init__(self, scene):
        dim = scene.dim
        faces = scene.walls.faces[: 2 * dim]
        self.lo = np.asarray(scene.domain_lo, dtype=np.float64)
        self.hi = np.asarray(scene.domain_hi, dtype=np.float64)
        self.conditions = np.array([CONDITIONS[f.condition] for f in faces], dtype=np.int64)
        self.frictions = np.array([f.friction for f in faces], dtype=np.float64)
        periodic = set(getattr(scene, "periodic", ()) or ())
        self.active = np.array([face // 2 not in periodic for face in range(2 * dim)])

    def apply(self, x, v, dt: float) -> int:
        return walls_on_particles(x, v, dt, self.lo, self.hi, self.conditions,
                                  self.frictions, self.active)


class ParticleColliders:
    """The scene's analytic colliders as they act on off-grid particles, in scene order
    (after the walls, as on the grid)."""

    def __init__(self, scene):
        self.colliders = make_colliders(scene)
        self.hits = 0

    def apply(self, x, v, t: float, dt: float) -> int:
        """Project v (n, d) in place for particles about to enter a collider over
        [t, t + dt]; returns the number of projections."""
        hits = sum(c.apply_to_particles(x, v, t, dt) for c in self.colliders)
        self.hits += hits
        return hits

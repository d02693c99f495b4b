"""Grid boundary conditions: domain walls, analytic colliders, prescribed particle sets.

Walls and colliders have ``apply(velocity, origin, dx, domain_lo, t, dt, mass=None)``, acting
in place on the rank-local grid velocity (block + (dim,)) after the explicit update; node j of
the block has global index ``origin + j`` and sits at ``domain_lo + (origin + j) * dx``.
Prescribed sets mark the support nodes of their particles after P2G and impose their rigid
velocity last, so a clamp wins over walls and colliders (`hpcmpm.boundaries.prescribed`).
"""

from __future__ import annotations

import numpy as np

from .colliders import Collider
from .prescribed import PrescribedSet, mark_prescribed_particles
from .walls import Walls


def build_boundaries(scene) -> list:
    """Walls (when the scene has them) followed by the colliders, in scene order. The faces
    of periodic axes are not walls."""
    out: list = []
    walls = getattr(scene, "walls", None)
    if walls is not None and walls.faces:
        n_cells = np.rint((np.asarray(scene.domain_hi) - np.asarray(scene.domain_lo))
                          / scene.dx).astype(np.int64)
        out.append(Walls(walls.faces, n_cells, getattr(scene, "periodic", ())))
    out.extend(make_colliders(scene))
    return out


def make_colliders(scene) -> list[Collider]:
    """The scene's colliders, with the periods of its periodic axes (their images act)."""
    return [Collider(spec, scene.dim, _periods(scene), scene.domain_lo)
            for spec in getattr(scene, "colliders", ())]


def build_prescribed(scene) -> list[PrescribedSet]:
    """One `PrescribedSet` per ``[[prescribed]]`` entry; its index is its position."""
    periods = _periods(scene)
    return [PrescribedSet(spec, i, scene.dim, periods)
            for i, spec in enumerate(scene.prescribed)]


def _periods(scene) -> np.ndarray:
    """(dim,) period lengths of the scene's periodic axes (`scene.axis_periods`), 0
    elsewhere."""
    from ..scene import axis_periods

    periods = np.zeros(scene.dim)
    for axis, period in axis_periods(getattr(scene, "periodic", ()), scene.domain_lo,
                                     scene.domain_hi):
        periods[axis] = period
    return periods


__all__ = ["Collider", "PrescribedSet", "Walls", "build_boundaries", "build_prescribed",
           "make_colliders", "mark_prescribed_particles"]

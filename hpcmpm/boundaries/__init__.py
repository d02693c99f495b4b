"""Grid boundary conditions: domain walls, analytic colliders, prescribed particle sets.

Walls and colliders have ``apply(velocity, origin, dx, domain_lo, t, dt, mass)``, called on
the grid velocity after the explicit update. Prescribed sets scatter node marks with P2G and
impose their rigid velocity last (`hpcmpm.boundaries.prescribed`).
"""

from __future__ import annotations

import numpy as np

from .colliders import Collider
from .prescribed import PrescribedSet, mark_prescribed_particles
from .walls import Walls


def build_boundaries(scene) -> list:
    """Walls (when the scene has them) followed by the colliders, in scene order."""
    out = []
    walls = getattr(scene, "walls", None)
    if walls is not None:
        n_cells = np.rint((np.asarray(scene.domain_hi) - np.asarray(scene.domain_lo))
                          / scene.dx).astype(np.int64)
        out.append(Walls(walls.faces, n_cells))
    out.extend(Collider(spec, scene.dim) for spec in getattr(scene, "colliders", ()))
    return out


def build_prescribed(scene) -> list[PrescribedSet]:
    return [PrescribedSet(spec, i, scene.dim) for i, spec in enumerate(scene.prescribed)]


__all__ = ["Collider", "PrescribedSet", "Walls", "build_boundaries", "build_prescribed",
           "mark_prescribed_particles"]

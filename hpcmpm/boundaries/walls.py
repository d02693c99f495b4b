"""Domain walls: the faces of the domain box act on the grid nodes on or beyond them
(global index ``i <= 0`` on a lower face, ``i >= n_cells`` on an upper face; ARCHITECTURE.md).

Each face is a static obstacle whose outward normal points into the domain; the projection is
`contact.project` (Stomakhin 2013 §8): sticky zeroes the velocity, slip removes its normal
component, separate removes it only for nodes moving out of the domain and applies Coulomb
friction to the tangential part.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._block import block3, mass3
from .contact import CONDITIONS, NO_BASIS, NO_COUNT, SEPARATE, constrain, project


@njit(cache=True)
def project_face(velocity, mass, use_mass, lo, hi, axis, normal_sign, condition, friction,
                 record, basis, count):
    """Project the velocity of every node in the index box ``lo <= j < hi`` (block indices)
    against one wall, or with ``record`` leave it and add the directions the wall fixes to
    ``basis``/``count`` (`contact.constrain`).

    velocity (n0, n1, n2, dim) and mass (n0, n1, n2) are 3D views of the block (n2 = 1 in 2D);
    ``normal_sign`` is the wall's outward normal along ``axis`` (+1 on a lower face: the wall
    pushes towards +axis). Nodes with zero mass are skipped when ``use_mass``."""
    dim = velocity.shape[3]
    n0 = normal_sign if axis == 0 else 0.0
    n1 = normal_sign if axis == 1 else 0.0
    n2 = normal_sign if axis == 2 else 0.0
    for i in range(lo[0], hi[0]):
        for j in range(lo[1], hi[1]):
            for k in range(lo[2], hi[2]):
                if use_mass and mass[i, j, k] <= 0.0:
                    continue
                v2 = velocity[i, j, k, 2] if dim == 3 else 0.0
                if record:
                    constrain(basis, count, i, j, k, velocity[i, j, k, 0], velocity[i, j, k, 1],
                              v2, n0, n1, n2, condition, dim)
                    continue
                r0, r1, r2 = project(velocity[i, j, k, 0], velocity[i, j, k, 1], v2,
                                     n0, n1, n2, condition, friction)
                velocity[i, j, k, 0] = r0
                velocity[i, j, k, 1] = r1
                if dim == 3:
                    velocity[i, j, k, 2] = r2


class Walls:
    """The 2*dim faces of the domain box (order x-, x+, y-, y+, z-, z+), each sticky, slip or
    separate with a Coulomb friction coefficient. The faces of the ``periodic`` axes (indices)
    do not act: the grid wraps there (`hpcmpm.parallel`)."""

    name = "walls"

    def __init__(self, faces, n_cells, periodic=()):
        self.faces = [(CONDITIONS[f.condition], float(f.friction)) for f in faces]
        self.n_cells = np.asarray(n_cells, dtype=np.int64)
        if len(self.faces) != 2 * len(self.n_cells):
            raise ValueError(f"walls need {2 * len(self.n_cells)} faces, got {len(self.faces)}")
        self.periodic = tuple(int(a) for a in periodic)
        self._key: tuple | None = None
        self._boxes: list[tuple] = []

    @property
    def frictional(self) -> bool:
        """Whether a face that acts is separate with friction (the semi-implicit step then
        needs its reactions: `SemiImplicitIntegrator._release_reactions`)."""
        return any(condition == SEPARATE and friction > 0.0 and face // 2 not in self.periodic
                   for face, (condition, friction) in enumerate(self.faces))

    def apply(self, velocity: np.ndarray, origin, dx: float, domain_lo, t: float, dt: float,
              mass: np.ndarray | None = None) -> None:
        """Act in place on ``velocity`` (block + (dim,)) whose node j has global index
        ``origin + j``; ``mass`` (block) lets massless nodes be skipped. Static: t, dt unused."""
        dim = velocity.shape[-1]
        v3 = block3(velocity, dim)
        m3, use_mass = mass3(mass, dim)
        key = (tuple(int(o) for o in origin), v3.shape[:3])
        if key != self._key:  # the block moved or grew: recompute which faces it touches
            self._key, self._boxes = key, self._face_boxes(*key)
        for lo, hi, axis, sign, condition, friction in self._boxes:
            project_face(v3, m3, use_mass, lo, hi, axis, sign, condition, friction, False,
                         NO_BASIS, NO_COUNT)

    def constrain(self, velocity: np.ndarray, origin, dx: float, domain_lo, t: float,
                  dt: float, mass: np.ndarray, basis: np.ndarray, count: np.ndarray) -> None:
        """Add the directions the walls fix at the trial ``velocity`` to ``basis`` (block3 +
        (3, 3)) and ``count`` (block3), for the semi-implicit solve's constraint mask."""
        dim = velocity.shape[-1]
        v3 = block3(velocity, dim)
        m3, use_mass = mass3(mass, dim)
        key = (tuple(int(o) for o in origin), v3.shape[:3])
        if key != self._key:
            self._key, self._boxes = key, self._face_boxes(*key)
        for lo, hi, axis, sign, condition, friction in self._boxes:
            project_face(v3, m3, use_mass, lo, hi, axis, sign, condition, friction, True,
                         basis, count)

    def _face_boxes(self, origin, shape) -> list[tuple]:
        """Per face the block reaches: (lo, hi) block-index box of the nodes on or beyond
        it, the axis, the outward normal sign, the condition and the friction."""
        boxes = []
        for face, (condition, friction) in enumerate(self.faces):
            axis, upper = divmod(face, 2)
            if axis in self.periodic:
                continue
            lo = np.zeros(3, dtype=np.int64)
            hi = np.array(shape, dtype=np.int64)
            if upper:  # block index of global node n_cells, and everything above it
                lo[axis] = max(self.n_cells[axis] - origin[axis], 0)
                sign = -1.0
            else:  # global nodes <= 0
                hi[axis] = min(1 - origin[axis], shape[axis])
                sign = 1.0
            if hi[axis] > lo[axis]:
                boxes.append((lo, hi, axis, sign, condition, friction))
        return boxes

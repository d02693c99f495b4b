"""Domain walls: the faces of the domain box act on the grid nodes on or beyond them
(global index ``i <= 0`` on a lower face, ``i >= n_cells`` on an upper face)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .contact import CONDITIONS, project


@njit(cache=True)
def apply_face(velocity, mass, axis, normal_sign, condition, friction):
    """Apply one wall to every node of ``velocity`` (flattened (N, dim) view of the slab
    beyond the face). ``normal_sign`` is the outward normal of the obstacle (+1 on a lower
    face: the wall pushes towards +axis)."""
    dim = velocity.shape[1]
    for n in range(velocity.shape[0]):
        if mass[n] <= 0.0:
            continue
        n0 = normal_sign if axis == 0 else 0.0
        n1 = normal_sign if axis == 1 else 0.0
        n2 = normal_sign if axis == 2 else 0.0
        v2 = velocity[n, 2] if dim == 3 else 0.0
        r0, r1, r2 = project(velocity[n, 0], velocity[n, 1], v2, n0, n1, n2, condition,
                             friction)
        velocity[n, 0] = r0
        velocity[n, 1] = r1
        if dim == 3:
            velocity[n, 2] = r2


class Walls:
    """The 2*dim faces of the domain box, each sticky, slip or separating with friction."""

    name = "walls"

    def __init__(self, faces, n_cells):
        self.faces = [(CONDITIONS[f.condition], float(f.friction)) for f in faces]
        self.n_cells = np.asarray(n_cells, dtype=np.int64)

    def apply(self, velocity, origin, dx, domain_lo, t, dt, mass) -> None:
        dim = velocity.shape[-1]
        shape = np.asarray(velocity.shape[:-1])
        for face, (condition, friction) in enumerate(self.faces):
            axis, upper = divmod(face, 2)
            if upper:
                start = self.n_cells[axis] - origin[axis]
                lo, hi, sign = max(start, 0), shape[axis], -1.0
            else:
                stop = -origin[axis] + 1
                lo, hi, sign = 0, min(stop, shape[axis]), 1.0
            if hi <= lo:
                continue
            index = [slice(None)] * dim
            index[axis] = slice(int(lo), int(hi))
            slab_v = np.ascontiguousarray(velocity[tuple(index)])
            slab_m = np.ascontiguousarray(mass[tuple(index)])
            apply_face(slab_v.reshape(-1, dim), slab_m.reshape(-1), axis, sign, condition,
                       friction)
            velocity[tuple(index)] = slab_v

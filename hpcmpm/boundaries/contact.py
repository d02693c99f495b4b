"""The velocity projection shared by walls and colliders (Stomakhin 2013 §8; 000 §3.5).

Given a node velocity ``v`` relative to the obstacle and the obstacle's outward normal ``n``:
- sticky: the relative velocity becomes zero;
- slip: its normal component is removed;
- separate: only when the node moves into the obstacle (``v.n < 0``) is the normal component
  removed, and the tangential part loses ``friction * |v.n|`` of its length (Coulomb), never
  reversing.

For the semi-implicit solve the same conditions act as a linear mask on the velocity
increments (`constrain`): at the trial velocity, sticky fixes every component, slip (and
separate while the node moves into the obstacle) the normal one; the fixed directions of a
node are kept as an orthonormal basis (``basis`` (n0, n1, n2, 3, 3) rows, ``count`` how many).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

STICKY, SLIP, SEPARATE = 0, 1, 2
CONDITIONS = {"sticky": STICKY, "slip": SLIP, "separate": SEPARATE}
# Stand in for the constraint arrays when a kernel projects velocities (never indexed).
NO_BASIS = np.zeros((1, 1, 1, 3, 3))
NO_COUNT = np.zeros((1, 1, 1), dtype=np.int64)


@njit(cache=True, inline="always")
def project(v0, v1, v2, n0, n1, n2, condition, friction):
    """Project relative velocity (v0, v1, v2) against outward normal (n0, n1, n2); returns
    the projected relative velocity. In 2D pass v2 = n2 = 0."""
    if condition == STICKY:
        return 0.0, 0.0, 0.0
    vn = v0 * n0 + v1 * n1 + v2 * n2
    if condition == SEPARATE and vn >= 0.0:
        return v0, v1, v2  # separating: free
    t0, t1, t2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
    if condition == SLIP or friction == 0.0:
        return t0, t1, t2
    vt = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if vt <= -friction * vn:
        return 0.0, 0.0, 0.0  # static friction holds the node
    scale = 1.0 + friction * vn / vt  # vn < 0: shortens the tangential velocity
    return t0 * scale, t1 * scale, t2 * scale


@njit(cache=True, inline="always")
def add_direction(basis, count, i, j, k, n0, n1, n2):
    """Add the unit direction n to node (i, j, k)'s constrained directions, orthogonalised
    against those it has (Gram-Schmidt); a direction already in their span is dropped."""
    c = count[i, j, k]
    for q in range(c):
        s = n0 * basis[i, j, k, q, 0] + n1 * basis[i, j, k, q, 1] + n2 * basis[i, j, k, q, 2]
        n0 -= s * basis[i, j, k, q, 0]
        n1 -= s * basis[i, j, k, q, 1]
        n2 -= s * basis[i, j, k, q, 2]
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if norm < 1e-8 or c >= 3:
        return
    basis[i, j, k, c, 0] = n0 / norm
    basis[i, j, k, c, 1] = n1 / norm
    basis[i, j, k, c, 2] = n2 / norm
    count[i, j, k] = c + 1


@njit(cache=True, inline="always")
def constrain(basis, count, i, j, k, v0, v1, v2, n0, n1, n2, condition, dim):
    """Record the directions the condition fixes at node (i, j, k) for relative trial
    velocity (v0, v1, v2) and outward normal (n0, n1, n2): every axis (sticky), the normal
    (slip; separate when ``v.n < 0``), or none (separate, moving away)."""
    if condition == STICKY:
        for a in range(dim):
            add_direction(basis, count, i, j, k, 1.0 if a == 0 else 0.0,
                          1.0 if a == 1 else 0.0, 1.0 if a == 2 else 0.0)
        return
    if condition == SEPARATE and v0 * n0 + v1 * n1 + v2 * n2 >= 0.0:
        return
    add_direction(basis, count, i, j, k, n0, n1, n2)

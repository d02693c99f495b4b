"""The velocity projection shared by walls and colliders (Stomakhin 2013 §8; 000 §3.5).

Given a node velocity ``v`` relative to the obstacle and the obstacle's outward normal ``n``:
- sticky: the relative velocity becomes zero;
- slip: its normal component is removed;
- separate: only when the node moves into the obstacle (``v.n < 0``) is the normal component
  removed, and the tangential part loses ``friction * |v.n|`` of its length (Coulomb), never
  reversing.
"""

from __future__ import annotations

import math

from numba import njit

STICKY, SLIP, SEPARATE = 0, 1, 2
CONDITIONS = {"sticky": STICKY, "slip": SLIP, "separate": SEPARATE}


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

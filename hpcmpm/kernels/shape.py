"""B-spline shape functions (000 §3.2, 003 eq. 3.3).

A particle at grid coordinate ``xi = (x - domain_lo) / dx`` interacts with the nodes
``base .. base + order`` along each axis. With ``r = xi - node`` (the particle-to-node distance
in cells):

- quadratic: ``N(r) = 3/4 - r^2`` for ``|r| < 1/2``, ``(3/2 - |r|)^2 / 2`` for ``1/2 <= |r| < 3/2``
  (003 eq. 3.3; the converted text garbles the middle case, this is Steffen 2008's form);
  ``base = floor(xi - 1/2)``.
- cubic: ``N(r) = |r|^3/2 - r^2 + 2/3`` for ``|r| < 1``, ``(2 - |r|)^3 / 6`` for ``1 <= |r| < 2``
  (000 eq. 3.2); ``base = floor(xi) - 1``.

For both, a particle in cell ``c`` touches nodes ``c-1 .. c+2``: the ghost layer is one node
below and two above a rank's owned cells. ``grad`` is dN/dx = N'(r) / dx. The APIC/MLS inertia
is ``D = dx^2 / 4`` (quadratic) or ``dx^2 / 3`` (cubic) times the identity (Jiang 2015 §5.2).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

QUADRATIC, CUBIC = 2, 3
ORDERS = {"quadratic": QUADRATIC, "cubic": CUBIC}


def inverse_inertia_factor(order: int) -> float:
    """``D^-1 * dx^2`` for APIC/MLS: 4 for quadratic, 3 for cubic B-splines."""
    return 4.0 if order == QUADRATIC else 3.0


@njit(cache=True, inline="always")
def stencil_base(xi: float, order: int) -> int:
    """Lowest node index touched by a particle at grid coordinate ``xi``."""
    if order == QUADRATIC:
        return int(math.floor(xi - 0.5))
    return int(math.floor(xi)) - 1


@njit(cache=True, inline="always")
def weights_1d(xi: float, base: int, order: int, inv_dx: float, w, dw, axis: int) -> None:
    """Fill ``w[axis, k]`` and ``dw[axis, k]`` (k = 0..order) for the nodes ``base + k``.

    ``w`` and ``dw`` are scratch arrays of shape (dim, 4) owned by the caller, so the
    per-particle loop allocates nothing."""
    if order == QUADRATIC:
        fx = xi - base  # in [0.5, 1.5)
        w[axis, 0] = 0.5 * (1.5 - fx) ** 2
        w[axis, 1] = 0.75 - (fx - 1.0) ** 2
        w[axis, 2] = 0.5 * (fx - 0.5) ** 2
        dw[axis, 0] = (fx - 1.5) * inv_dx
        dw[axis, 1] = -2.0 * (fx - 1.0) * inv_dx
        dw[axis, 2] = (fx - 0.5) * inv_dx
    else:
        for k in range(4):
            r = xi - (base + k)
            a = abs(r)
            s = 1.0 if r >= 0.0 else -1.0
            if a < 1.0:
                w[axis, k] = 0.5 * a * a * a - a * a + 2.0 / 3.0
                dw[axis, k] = (1.5 * a * a - 2.0 * a) * s * inv_dx
            elif a < 2.0:
                t = 2.0 - a
                w[axis, k] = t * t * t / 6.0
                dw[axis, k] = -0.5 * t * t * s * inv_dx
            else:
                w[axis, k] = 0.0
                dw[axis, k] = 0.0


@njit(cache=True)
def evaluate(xi: np.ndarray, order: int, inv_dx: float):
    """Weights and gradients of every particle at grid coordinates ``xi`` (n, dim).

    Returns ``base`` (n, dim) int64, ``w`` and ``dw`` (n, dim, order + 1). For tests and
    diagnostics; the transfer kernels inline `weights_1d` instead."""
    n, dim = xi.shape
    s = order + 1
    base = np.empty((n, dim), dtype=np.int64)
    w = np.empty((n, dim, s))
    dw = np.empty((n, dim, s))
    sw = np.empty((dim, 4))
    sdw = np.empty((dim, 4))
    for p in range(n):
        for a in range(dim):
            b = stencil_base(xi[p, a], order)
            base[p, a] = b
            weights_1d(xi[p, a], b, order, inv_dx, sw, sdw, a)
            for k in range(s):
                w[p, a, k] = sw[a, k]
                dw[p, a, k] = sdw[a, k]
    return base, w, dw

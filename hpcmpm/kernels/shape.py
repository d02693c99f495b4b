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
from numba import njit, uint64

QUADRATIC, CUBIC = 2, 3
ORDERS = {"quadratic": QUADRATIC, "cubic": CUBIC}

# A stencil node's index into the rank's block as an unsigned integer: the offset
# ``node(base - origin)`` and the stencil counters ``range(node(s))`` alike (numba types
# uint64 + int64 as float64). Through a signed index numba adds a wraparound for negative
# values (a compare and a select per axis of every access) unless it can prove the index
# >= 0, which it cannot for ``base - origin + i``; the block holds every particle's whole
# stencil, so that index never is negative and the wraparound is dead code. Measured on the
# transfer and solve kernels: BENCHMARKS.md, "Unsigned stencil indices".
node = uint64


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
def weights(xi: float, base: int, order: int, inv_dx: float):
    """``(w, dw)``: two 4-tuples of the weights and gradients at nodes ``base .. base + 3``
    (the fourth entries are zero for the quadratic spline), with ``r = xi - node``.

    Tuples, not a scratch array: with ``order`` a compile-time constant (see
    `hpcmpm.kernels.transfer.static`) the stencil loops unroll and the weights stay in
    registers, where a scratch array would be reloaded after every grid store (the compiler
    cannot prove the two do not alias). For the cubic spline ``xi - base`` is in [1, 2), so
    the branch of each node and the sign of its ``r`` are known."""
    fx = xi - base
    if order == QUADRATIC:  # fx in [0.5, 1.5)
        return ((0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2, 0.0),
                ((fx - 1.5) * inv_dx, -2.0 * (fx - 1.0) * inv_dx, (fx - 0.5) * inv_dx, 0.0))
    a1 = fx - 1.0  # |r| at node base + 1 (r >= 0)
    a2 = 2.0 - fx  # |r| at node base + 2 (r <= 0)
    t0 = 2.0 - fx  # 2 - |r| at node base (r in [1, 2))
    t3 = fx - 1.0  # 2 - |r| at node base + 3 (r in [-2, -1))
    return ((t0 * t0 * t0 / 6.0, 0.5 * a1 * a1 * a1 - a1 * a1 + 2.0 / 3.0,
             0.5 * a2 * a2 * a2 - a2 * a2 + 2.0 / 3.0, t3 * t3 * t3 / 6.0),
            (-0.5 * t0 * t0 * inv_dx, (1.5 * a1 * a1 - 2.0 * a1) * inv_dx,
             -(1.5 * a2 * a2 - 2.0 * a2) * inv_dx, 0.5 * t3 * t3 * inv_dx))


@njit(cache=True)
def evaluate(xi: np.ndarray, order: int, inv_dx: float):
    """Weights and gradients of every particle at grid coordinates ``xi`` (n, dim).

    Returns ``base`` (n, dim) int64, ``w`` and ``dw`` (n, dim, order + 1). For tests and
    diagnostics; the transfer kernels inline `weights` instead."""
    n, dim = xi.shape
    s = order + 1
    base = np.empty((n, dim), dtype=np.int64)
    w = np.empty((n, dim, s))
    dw = np.empty((n, dim, s))
    for p in range(n):
        for a in range(dim):
            b = stencil_base(xi[p, a], order)
            base[p, a] = b
            wa, dwa = weights(xi[p, a], b, order, inv_dx)
            for k in range(s):
                w[p, a, k] = wa[k]
                dw[p, a, k] = dwa[k]
    return base, w, dw


@njit(cache=True, inline="always")
def stencil_weights_2d(x, p, order, inv_dx, domain_lo, origin):
    """(w0, w1, l0, l1): the weights along each axis of particle p (row of x) and its first
    stencil node in block-local indices (``origin`` the block's first node; unsigned,
    `node`: loop over the stencil with ``range(node(s))``), for the transfers that need no
    gradient."""
    xi0 = (x[p, 0] - domain_lo[0]) * inv_dx
    xi1 = (x[p, 1] - domain_lo[1]) * inv_dx
    b0 = stencil_base(xi0, order)
    b1 = stencil_base(xi1, order)
    w0, _ = weights(xi0, b0, order, inv_dx)
    w1, _ = weights(xi1, b1, order, inv_dx)
    return w0, w1, node(b0 - origin[0]), node(b1 - origin[1])


@njit(cache=True, inline="always")
def stencil_weights_3d(x, p, order, inv_dx, domain_lo, origin):
    """`stencil_weights_2d` in 3D: (w0, w1, w2, l0, l1, l2)."""
    xi0 = (x[p, 0] - domain_lo[0]) * inv_dx
    xi1 = (x[p, 1] - domain_lo[1]) * inv_dx
    xi2 = (x[p, 2] - domain_lo[2]) * inv_dx
    b0 = stencil_base(xi0, order)
    b1 = stencil_base(xi1, order)
    b2 = stencil_base(xi2, order)
    w0, _ = weights(xi0, b0, order, inv_dx)
    w1, _ = weights(xi1, b1, order, inv_dx)
    w2, _ = weights(xi2, b2, order, inv_dx)
    return w0, w1, w2, node(b0 - origin[0]), node(b1 - origin[1]), node(b2 - origin[2])

"""Volume averaging through the grid (``simulation.volume_averaging = "grid"``).

A particle's volume ratio J is replaced by the grid average at its position:

    J_i = sum_p w_ip m_p J_p / sum_p w_ip m_p,        J_p <- sum_i w_ip J_i,

with the weights of the step's P2G (the particles at x^n). It is the nodal averaging of the
volumetric deformation used against volumetric locking and pressure noise in MPM (the
"F-bar" of Coombs, Charlton, Cortis & Augarde 2018, here on a stored J: the models that carry
J as state read their pressure from it). It conserves the total volume: with
sum_i w_ip = 1, sum_p m_p J_p (new) = sum_i m_i J_i = sum_p m_p J_p (old), and a uniform J
is kept to round-off.

The scatter adds to the block's nodes; the engine sums the partial node values of other
ranks to their owners, divides on every node (`nodal_average`), fills the ghost copies from
the owners, then gathers.
"""

from __future__ import annotations

from numba import njit

from .shape import stencil_base, weights


@njit(cache=True, inline="always")
def _stencil_2d(x, p, order, inv_dx, domain_lo, origin):
    """(w0, w1, l0, l1): particle p's weights per axis and its first block-local node."""
    xi0 = (x[p, 0] - domain_lo[0]) * inv_dx
    xi1 = (x[p, 1] - domain_lo[1]) * inv_dx
    b0 = stencil_base(xi0, order)
    b1 = stencil_base(xi1, order)
    w0, _ = weights(xi0, b0, order, inv_dx)
    w1, _ = weights(xi1, b1, order, inv_dx)
    return w0, w1, b0 - origin[0], b1 - origin[1]


@njit(cache=True, inline="always")
def _stencil_3d(x, p, order, inv_dx, domain_lo, origin):
    """`_stencil_2d` in 3D: (w0, w1, w2, l0, l1, l2)."""
    xi0 = (x[p, 0] - domain_lo[0]) * inv_dx
    xi1 = (x[p, 1] - domain_lo[1]) * inv_dx
    xi2 = (x[p, 2] - domain_lo[2]) * inv_dx
    b0 = stencil_base(xi0, order)
    b1 = stencil_base(xi1, order)
    b2 = stencil_base(xi2, order)
    w0, _ = weights(xi0, b0, order, inv_dx)
    w1, _ = weights(xi1, b1, order, inv_dx)
    w2, _ = weights(xi2, b2, order, inv_dx)
    return w0, w1, w2, b0 - origin[0], b1 - origin[1], b2 - origin[2]


@njit(cache=True)
def scatter_volume_2d(x, mass, J, order, dx, domain_lo, origin, grid_mass, grid_mJ):
    """grid_mass += sum_p w_ip m_p, grid_mJ += sum_p w_ip m_p J_p (2D, block-local nodes)."""
    order = len(order)  # compile-time constant: see transfer.static
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, l0, l1 = _stencil_2d(x, p, order, inv_dx, domain_lo, origin)
        m = mass[p]
        mj = m * J[p]
        for i in range(s):
            for j in range(s):
                w = w0[i] * w1[j]
                grid_mass[l0 + i, l1 + j] += w * m
                grid_mJ[l0 + i, l1 + j] += w * mj


@njit(cache=True)
def scatter_volume_3d(x, mass, J, order, dx, domain_lo, origin, grid_mass, grid_mJ):
    """`scatter_volume_2d` in 3D."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, w2, l0, l1, l2 = _stencil_3d(x, p, order, inv_dx, domain_lo, origin)
        m = mass[p]
        mj = m * J[p]
        for i in range(s):
            for j in range(s):
                wij = w0[i] * w1[j]
                for k in range(s):
                    w = wij * w2[k]
                    grid_mass[l0 + i, l1 + j, l2 + k] += w * m
                    grid_mJ[l0 + i, l1 + j, l2 + k] += w * mj


@njit(cache=True)
def nodal_average(grid_mass, grid_mJ):
    """grid_mJ <- grid_mJ / grid_mass in place where the mass is positive (flat views)."""
    for k in range(grid_mass.shape[0]):
        if grid_mass[k] > 0.0:
            grid_mJ[k] /= grid_mass[k]


@njit(cache=True)
def gather_volume_2d(x, order, dx, domain_lo, origin, grid_J, J):
    """J_p <- sum_i w_ip J_i (2D)."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, l0, l1 = _stencil_2d(x, p, order, inv_dx, domain_lo, origin)
        acc = 0.0
        for i in range(s):
            for j in range(s):
                acc += w0[i] * w1[j] * grid_J[l0 + i, l1 + j]
        J[p] = acc


@njit(cache=True)
def gather_volume_3d(x, order, dx, domain_lo, origin, grid_J, J):
    """`gather_volume_2d` in 3D."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, w2, l0, l1, l2 = _stencil_3d(x, p, order, inv_dx, domain_lo, origin)
        acc = 0.0
        for i in range(s):
            for j in range(s):
                wij = w0[i] * w1[j]
                for k in range(s):
                    acc += wij * w2[k] * grid_J[l0 + i, l1 + j, l2 + k]
        J[p] = acc


SCATTER_VOLUME = {2: scatter_volume_2d, 3: scatter_volume_3d}
GATHER_VOLUME = {2: gather_volume_2d, 3: gather_volume_3d}

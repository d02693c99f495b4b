"""Volume averaging through the grid (``simulation.volume_averaging = "increment"``).

Each step's change of a particle's volume ratio J is replaced by its grid average. With J^n
and x^n kept before G2P and J^{n+1} the materials' state after the step,

    r_i = sum_p w_ip V0_p J_p^{n+1} / sum_p w_ip V0_p J_p^n,    J_p^{n+1} <- J_p^n sum_i w_ip r_i,

with the weights of the step's P2G (at x^n) and V0_p the initial volume, so V0_p J_p is the
particle's volume and r_i the node's ratio of new to old volume, whatever the materials'
densities. The average acts on the increment: a state at rest (J^{n+1} = J^n) is kept exactly, and
particle-scale noise in det(I + dt L_p) is removed before it accumulates. It is the nodal
averaging of the volumetric deformation that MPM codes use against volumetric locking and
pressure noise (the F-bar of Coombs, Charlton, Cortis & Augarde 2018, on the increment of a
stored J). It conserves the total volume: sum_p V0_p J_p^n sum_i w_ip r_i =
sum_i r_i sum_p w_ip V0_p J_p^n = sum_p V0_p J_p^{n+1}; a uniform ratio is kept to round-off.

A particle whose new J is not finite (an inadmissible state the health check reports next)
neither contributes nor is changed, so the report names it and not its neighbours.

The scatter adds to the block's nodes; the engine sums the partial node values of other
ranks to their owners, divides on every node (`nodal_ratio`), fills the ghost copies from
the owners, then gathers.
"""

from __future__ import annotations

import math

from numba import njit

from .shape import node, stencil_weights_2d, stencil_weights_3d


@njit(cache=True)
def scatter_volume_2d(x, vol0, J_old, J_new, order, dx, domain_lo, origin, grid_old, grid_new):
    """grid_old += sum_p w_ip V0_p J_p^n, grid_new += sum_p w_ip V0_p J_p^{n+1} (2D,
    block-local nodes, weights at x = x^n)."""
    order = len(order)  # compile-time constant: see transfer.static
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        if not math.isfinite(J_new[p]):
            continue
        w0, w1, l0, l1 = stencil_weights_2d(x, p, order, inv_dx, domain_lo, origin)
        vo = vol0[p] * J_old[p]
        vn = vol0[p] * J_new[p]
        for i in range(node(s)):
            for j in range(node(s)):
                w = w0[i] * w1[j]
                grid_old[l0 + i, l1 + j] += w * vo
                grid_new[l0 + i, l1 + j] += w * vn


@njit(cache=True)
def scatter_volume_3d(x, vol0, J_old, J_new, order, dx, domain_lo, origin, grid_old, grid_new):
    """`scatter_volume_2d` in 3D."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        if not math.isfinite(J_new[p]):
            continue
        w0, w1, w2, l0, l1, l2 = stencil_weights_3d(x, p, order, inv_dx, domain_lo, origin)
        vo = vol0[p] * J_old[p]
        vn = vol0[p] * J_new[p]
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    w = wij * w2[k]
                    grid_old[l0 + i, l1 + j, l2 + k] += w * vo
                    grid_new[l0 + i, l1 + j, l2 + k] += w * vn


@njit(cache=True)
def nodal_ratio(grid_old, grid_new):
    """grid_new <- grid_new / grid_old in place where the old volume is positive (flat
    views): each node's ratio r_i of new to old volume."""
    for k in range(grid_old.shape[0]):
        if grid_old[k] > 0.0:
            grid_new[k] /= grid_old[k]


@njit(cache=True)
def gather_volume_2d(x, J_old, order, dx, domain_lo, origin, grid_r, J):
    """J_p <- J_p^n sum_i w_ip r_i (2D) where J_p is finite."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        if not math.isfinite(J[p]):
            continue
        w0, w1, l0, l1 = stencil_weights_2d(x, p, order, inv_dx, domain_lo, origin)
        acc = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                acc += w0[i] * w1[j] * grid_r[l0 + i, l1 + j]
        J[p] = J_old[p] * acc


@njit(cache=True)
def gather_volume_3d(x, J_old, order, dx, domain_lo, origin, grid_r, J):
    """`gather_volume_2d` in 3D."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        if not math.isfinite(J[p]):
            continue
        w0, w1, w2, l0, l1, l2 = stencil_weights_3d(x, p, order, inv_dx, domain_lo, origin)
        acc = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    acc += wij * w2[k] * grid_r[l0 + i, l1 + j, l2 + k]
        J[p] = J_old[p] * acc


SCATTER_VOLUME = {2: scatter_volume_2d, 3: scatter_volume_3d}
GATHER_VOLUME = {2: gather_volume_2d, 3: gather_volume_3d}

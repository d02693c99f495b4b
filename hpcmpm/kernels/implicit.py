"""Kernels of the semi-implicit step (000 §3.4, §5.5, appendix A; Stomakhin 2013; Gast 2015).

The unknown is the grid velocity v_hat; a particle sees it through its velocity gradient

    L_p(v) = sum_i v_i (grad w_ip)^T                                     (000 §5.5)

with the weights at x^n. Every grid-level quantity of the solve is one of four particle loops:

- `CONTRACT`: a grid vector u to L_p(u) (the same sum G2P forms for the step's L);
- `SCATTER_TENSOR`: per-particle tensors G_p (n, d, d) to ``out_i += scale sum_p G_p grad w_ip``
  (with G_p = de_p/dL_p and scale -1 this is the grid force -dPhi/dv_hat; with dG_p =
  D^2 e_p[dL_p] and scale +1 the material part of the Hessian-vector product);
- `HESSIAN_PRODUCT`: the material part of H u in one particle loop, from each particle's
  tangent T_p = D^2 e_p (d^2 x d^2, built once per linearization from d^2 material Hessian
  products; stored as its upper triangle, kernels/tangent.py): `CONTRACT`, T_p and
  `SCATTER_TENSOR` fused;
- `SCATTER_DIAGONAL`: the diagonal of the material Hessian,
  ``out_ia += sum_p sum_bc K_p[a, b, c] g_b g_c`` with K_p[a, b, c] = d^2 e_p/dL_ab dL_ac and
  g = grad w_ip (the Jacobi preconditioner).

"grad w" is the B-spline gradient for PIC, FLIP and APIC, and the MLS gradient
``w_ip D^-1 (x_i - x_p)`` for MLS-MPM, so that L_p is exactly the L (= C) that G2P stores
for every transfer and the solve's force is the force of the explicit step. The scheme
enters as ``static(mls)``, the kernel order as ``static(order)`` (`kernels.transfer.static`).

The rest are flat grid loops over (N,) scalars and (N, d) vectors (any block viewed with
``reshape(-1, d)``): the constraint projection and the vector updates of the conjugate
gradient.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .shape import node, stencil_base, weights
from .tangent import packed_index

# Cyclic Jacobi sweeps for a tangent's eigen-decomposition (`project_tangents_psd`):
# quadratic convergence leaves a 9 x 9 diagonal at round-off in well under ten.
JACOBI_SWEEPS = 30


@njit(cache=True, inline="always")
def weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx):
    """grad w_ip of stencil node (i, j) in 2D: MLS's ``w D^-1 (x_i - x_p)`` (e = the stencil
    base's offset from x_p) or the B-spline gradient; the one definition every loop below
    uses, so L_p, the force and the Hessian product see the same gradient."""
    if mls:
        wd = w0[i] * w1[j] * dinv
        return wd * (e0 + i * dx), wd * (e1 + j * dx)
    return dw0[i] * w1[j], w0[i] * dw1[j]


@njit(cache=True, inline="always")
def weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2, dinv, e0, e1, e2, dx):
    """3D version of `weight_gradient_2d`; wij = w0[i] w1[j], hoisted out of the k loop."""
    if mls:
        wd = wij * w2[k] * dinv
        return wd * (e0 + i * dx), wd * (e1 + j * dx), wd * (e2 + k * dx)
    return dw0[i] * w1[j] * w2[k], w0[i] * dw1[j] * w2[k], wij * dw2[k]


@njit(cache=True)
def contract_2d(x, u, mls, order, dinv_factor, dx, domain_lo, origin, L):
    """L_p = sum_i u_i grad w_ip^T in 2D. x (n, 2); u (nx, ny, 2) on the block; L (n, 2, 2)."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        l0, l1 = node(b0 - o0), node(b1 - o1)
        a00 = a01 = a10 = a11 = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                g0, g1 = weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx)
                u0, u1 = u[l0 + i, l1 + j, 0], u[l0 + i, l1 + j, 1]
                a00 += u0 * g0
                a01 += u0 * g1
                a10 += u1 * g0
                a11 += u1 * g1
        L[p, 0, 0], L[p, 0, 1], L[p, 1, 0], L[p, 1, 1] = a00, a01, a10, a11


@njit(cache=True)
def contract_3d(x, u, mls, order, dinv_factor, dx, domain_lo, origin, L):
    """L_p = sum_i u_i grad w_ip^T in 3D; see `contract_2d`."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        l0, l1, l2 = node(b0 - o0), node(b1 - o1), node(b2 - o2)
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    g0, g1, g2 = weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2,
                                                    dinv, e0, e1, e2, dx)
                    n0, n1, n2 = l0 + i, l1 + j, l2 + k
                    u0, u1, u2 = u[n0, n1, n2, 0], u[n0, n1, n2, 1], u[n0, n1, n2, 2]
                    a00 += u0 * g0
                    a01 += u0 * g1
                    a02 += u0 * g2
                    a10 += u1 * g0
                    a11 += u1 * g1
                    a12 += u1 * g2
                    a20 += u2 * g0
                    a21 += u2 * g1
                    a22 += u2 * g2
        L[p, 0, 0], L[p, 0, 1], L[p, 0, 2] = a00, a01, a02
        L[p, 1, 0], L[p, 1, 1], L[p, 1, 2] = a10, a11, a12
        L[p, 2, 0], L[p, 2, 1], L[p, 2, 2] = a20, a21, a22


@njit(cache=True)
def scatter_tensor_2d(x, G, scale, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """out_i += scale sum_p G_p grad w_ip in 2D. G (n, 2, 2); out (nx, ny, 2), in place."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        l0, l1 = node(b0 - o0), node(b1 - o1)
        t00, t01 = scale * G[p, 0, 0], scale * G[p, 0, 1]
        t10, t11 = scale * G[p, 1, 0], scale * G[p, 1, 1]
        for i in range(node(s)):
            for j in range(node(s)):
                g0, g1 = weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx)
                out[l0 + i, l1 + j, 0] += t00 * g0 + t01 * g1
                out[l0 + i, l1 + j, 1] += t10 * g0 + t11 * g1


@njit(cache=True)
def scatter_tensor_3d(x, G, scale, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """out_i += scale sum_p G_p grad w_ip in 3D; see `scatter_tensor_2d`."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        l0, l1, l2 = node(b0 - o0), node(b1 - o1), node(b2 - o2)
        t00, t01, t02 = scale * G[p, 0, 0], scale * G[p, 0, 1], scale * G[p, 0, 2]
        t10, t11, t12 = scale * G[p, 1, 0], scale * G[p, 1, 1], scale * G[p, 1, 2]
        t20, t21, t22 = scale * G[p, 2, 0], scale * G[p, 2, 1], scale * G[p, 2, 2]
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    g0, g1, g2 = weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2,
                                                    dinv, e0, e1, e2, dx)
                    n0, n1, n2 = l0 + i, l1 + j, l2 + k
                    out[n0, n1, n2, 0] += t00 * g0 + t01 * g1 + t02 * g2
                    out[n0, n1, n2, 1] += t10 * g0 + t11 * g1 + t12 * g2
                    out[n0, n1, n2, 2] += t20 * g0 + t21 * g1 + t22 * g2


@njit(cache=True)
def scatter_diagonal_2d(x, K, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """out_ia += sum_p sum_bc K_p[a, b, c] g_b g_c, g = grad w_ip, in 2D: the diagonal of
    sum_p D^2 e_p contracted with the weight gradients. K (n, 2, 2, 2); out (nx, ny, 2)."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        l0, l1 = node(b0 - o0), node(b1 - o1)
        # K_p in scalars: read in the node loop, its loads were repeated per node (the
        # stores to out may alias K for all the compiler knows).
        ka00, ka01, ka11 = K[p, 0, 0, 0], K[p, 0, 0, 1] + K[p, 0, 1, 0], K[p, 0, 1, 1]
        kb00, kb01, kb11 = K[p, 1, 0, 0], K[p, 1, 0, 1] + K[p, 1, 1, 0], K[p, 1, 1, 1]
        for i in range(node(s)):
            for j in range(node(s)):
                g0, g1 = weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx)
                out[l0 + i, l1 + j, 0] += ka00 * g0 * g0 + ka01 * g0 * g1 + ka11 * g1 * g1
                out[l0 + i, l1 + j, 1] += kb00 * g0 * g0 + kb01 * g0 * g1 + kb11 * g1 * g1


@njit(cache=True)
def scatter_diagonal_3d(x, K, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """3D version of `scatter_diagonal_2d`; K (n, 3, 3, 3)."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        l0, l1, l2 = node(b0 - o0), node(b1 - o1), node(b2 - o2)
        # K_p in scalars (see `scatter_diagonal_2d`): measured 2.6x a Hessian product's time
        # with the loads in the node loop.
        q0 = _diagonal_row(K, p, 0)
        q1 = _diagonal_row(K, p, 1)
        q2 = _diagonal_row(K, p, 2)
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    g0, g1, g2 = weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2,
                                                    dinv, e0, e1, e2, dx)
                    n0, n1, n2 = l0 + i, l1 + j, l2 + k
                    out[n0, n1, n2, 0] += _diagonal_term(q0, g0, g1, g2)
                    out[n0, n1, n2, 1] += _diagonal_term(q1, g0, g1, g2)
                    out[n0, n1, n2, 2] += _diagonal_term(q2, g0, g1, g2)


@njit(cache=True, inline="always")
def _diagonal_row(K, p, a):
    """K_p[a]'s six distinct terms of g.K_p[a].g: the diagonal and the summed off-diagonal
    pairs."""
    return (K[p, a, 0, 0], K[p, a, 1, 1], K[p, a, 2, 2], K[p, a, 0, 1] + K[p, a, 1, 0],
            K[p, a, 0, 2] + K[p, a, 2, 0], K[p, a, 1, 2] + K[p, a, 2, 1])


@njit(cache=True, inline="always")
def _diagonal_term(q, g0, g1, g2):
    """g.K_p[a].g from `_diagonal_row`'s terms."""
    return (q[0] * g0 * g0 + q[1] * g1 * g1 + q[2] * g2 * g2 + q[3] * g0 * g1
            + q[4] * g0 * g2 + q[5] * g1 * g2)


@njit(cache=True)
def hessian_product_2d(x, T, u, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """out_i += sum_p (T_p : dL_p) grad w_ip with dL_p = sum_j u_j grad w_jp^T in 2D: the
    material part of a Hessian-vector product in one pass, from the tangent
    T_p[ab, ce] = d^2 e_p / dL_ab dL_ce that `solvers.semi_implicit` builds once per
    linearization, packed (n, 10) as kernels/tangent.py lays it out. `contract_2d`, the
    tangent and `scatter_tensor_2d` fused."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        l0, l1 = node(b0 - o0), node(b1 - o1)
        a0 = a1 = a2 = a3 = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                g0, g1 = weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx)
                u0, u1 = u[l0 + i, l1 + j, 0], u[l0 + i, l1 + j, 1]
                a0 += u0 * g0
                a1 += u0 * g1
                a2 += u1 * g0
                a3 += u1 * g1
        # T_p's packed upper triangle (kernels/tangent.py): rows 0-3 start at 0, 4, 7, 9.
        q = T[p]
        t0 = q[0] * a0 + q[1] * a1 + q[2] * a2 + q[3] * a3
        t1 = q[1] * a0 + q[4] * a1 + q[5] * a2 + q[6] * a3
        t2 = q[2] * a0 + q[5] * a1 + q[7] * a2 + q[8] * a3
        t3 = q[3] * a0 + q[6] * a1 + q[8] * a2 + q[9] * a3
        for i in range(node(s)):
            for j in range(node(s)):
                g0, g1 = weight_gradient_2d(mls, i, j, w0, w1, dw0, dw1, dinv, e0, e1, dx)
                out[l0 + i, l1 + j, 0] += t0 * g0 + t1 * g1
                out[l0 + i, l1 + j, 1] += t2 * g0 + t3 * g1


@njit(cache=True)
def hessian_product_3d(x, T, u, mls, order, dinv_factor, dx, domain_lo, origin, out):
    """3D version of `hessian_product_2d`; T packed (n, 45)."""
    mls, order = len(mls) > 0, len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        l0, l1, l2 = node(b0 - o0), node(b1 - o1), node(b2 - o2)
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = 0.0
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    g0, g1, g2 = weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2,
                                                    dinv, e0, e1, e2, dx)
                    n0, n1, n2 = l0 + i, l1 + j, l2 + k
                    u0, u1, u2 = u[n0, n1, n2, 0], u[n0, n1, n2, 1], u[n0, n1, n2, 2]
                    a0 += u0 * g0
                    a1 += u0 * g1
                    a2 += u0 * g2
                    a3 += u1 * g0
                    a4 += u1 * g1
                    a5 += u1 * g2
                    a6 += u2 * g0
                    a7 += u2 * g1
                    a8 += u2 * g2
        q = T[p]  # T_p packed (kernels/tangent.py)
        t0 = _row9(q, 0, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t1 = _row9(q, 1, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t2 = _row9(q, 2, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t3 = _row9(q, 3, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t4 = _row9(q, 4, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t5 = _row9(q, 5, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t6 = _row9(q, 6, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t7 = _row9(q, 7, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        t8 = _row9(q, 8, a0, a1, a2, a3, a4, a5, a6, a7, a8)
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    g0, g1, g2 = weight_gradient_3d(mls, i, j, k, wij, w0, w1, w2, dw0, dw1, dw2,
                                                    dinv, e0, e1, e2, dx)
                    n0, n1, n2 = l0 + i, l1 + j, l2 + k
                    out[n0, n1, n2, 0] += t0 * g0 + t1 * g1 + t2 * g2
                    out[n0, n1, n2, 1] += t3 * g0 + t4 * g1 + t5 * g2
                    out[n0, n1, n2, 2] += t6 * g0 + t7 * g1 + t8 * g2


@njit(cache=True, inline="always")
def _row9(q, r, a0, a1, a2, a3, a4, a5, a6, a7, a8):
    """Row r of a packed 9 x 9 tangent (kernels/tangent.py) times (a0, ..., a8)."""
    return (q[packed_index(r, 0, 9)] * a0 + q[packed_index(r, 1, 9)] * a1
            + q[packed_index(r, 2, 9)] * a2 + q[packed_index(r, 3, 9)] * a3
            + q[packed_index(r, 4, 9)] * a4 + q[packed_index(r, 5, 9)] * a5
            + q[packed_index(r, 6, 9)] * a6 + q[packed_index(r, 7, 9)] * a7
            + q[packed_index(r, 8, 9)] * a8)


CONTRACT = {2: contract_2d, 3: contract_3d}
SCATTER_TENSOR = {2: scatter_tensor_2d, 3: scatter_tensor_3d}
SCATTER_DIAGONAL = {2: scatter_diagonal_2d, 3: scatter_diagonal_3d}
HESSIAN_PRODUCT = {2: hessian_product_2d, 3: hessian_product_3d}


# -- flat grid loops: u (N, d) vectors, free (N,) 0/1 ------------------------------------------
@njit(cache=True)
def project(u, free, nodes, basis, count):
    """The linear constraint mask, in place: u_i <- free_i (I - sum_k q_k q_k^T) u_i.

    free (N,) is 1 on the unknowns' nodes (owned, with mass) and 0 elsewhere; nodes (k,)
    lists the constrained nodes, basis (k, 3, 3) their orthonormal constrained directions
    (rows, padded to 3 components) and count (k,) how many of them each has."""
    d = u.shape[1]
    for n in range(u.shape[0]):
        if free[n] == 0.0:
            for a in range(d):
                u[n, a] = 0.0
    constrain(u, free, nodes, basis, count)


@njit(cache=True)
def constrain(u, free, nodes, basis, count):
    """u_i <- (I - sum_k q_k q_k^T) u_i on the constrained nodes that are unknowns (`project`
    without its zeroing of the other nodes, which it leaves as they are)."""
    d = u.shape[1]
    for k in range(nodes.shape[0]):
        n = nodes[k]
        if free[n] == 0.0:
            continue
        for c in range(count[k]):
            s = 0.0
            for a in range(d):
                s += u[n, a] * basis[k, c, a]
            for a in range(d):
                u[n, a] -= s * basis[k, c, a]


@njit(cache=True)
def project_tangents_psd(T):
    """Replace each tangent T_p (the d^2 x d^2 d^2e_p/dL dL of `_tangent`, packed (n, m) as
    kernels/tangent.py lays it out) that has a negative eigenvalue by the nearest positive
    semi-definite matrix, Q max(Lambda, 0) Q^T (Teran et al. 2005's definiteness fix, per
    particle: the grid Hessian M + sum_p B_p^T T_p B_p is then positive definite on the
    unknowns). The eigen-decomposition is cyclic Jacobi on scratch allocated once. Tangents
    without a negative eigenvalue are left exactly as they were. Returns how many were
    changed."""
    n, m = T.shape[0], T.shape[1]
    k = 0
    while k * (k + 1) // 2 < m:
        k += 1
    a = np.empty((k, k))
    q = np.empty((k, k))
    changed = 0
    for p in range(n):
        scale = 0.0
        for i in range(k):
            for j in range(k):
                a[i, j] = T[p, packed_index(i, j, k)]
                q[i, j] = 1.0 if i == j else 0.0
                scale += a[i, j] * a[i, j]
        for sweep in range(JACOBI_SWEEPS):
            off = 0.0
            for i in range(k - 1):
                for j in range(i + 1, k):
                    off += a[i, j] * a[i, j]
            if off <= 1e-30 * scale:
                break
            for i in range(k - 1):
                for j in range(i + 1, k):
                    if a[i, j] == 0.0:
                        continue
                    theta = (a[j, j] - a[i, i]) / (2.0 * a[i, j])
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                    c = 1.0 / math.sqrt(t * t + 1.0)
                    s = t * c
                    for r in range(k):  # A J
                        ari, arj = a[r, i], a[r, j]
                        a[r, i] = c * ari - s * arj
                        a[r, j] = s * ari + c * arj
                    for r in range(k):  # J^T (A J)
                        air, ajr = a[i, r], a[j, r]
                        a[i, r] = c * air - s * ajr
                        a[j, r] = s * air + c * ajr
                    for r in range(k):  # Q J
                        qri, qrj = q[r, i], q[r, j]
                        q[r, i] = c * qri - s * qrj
                        q[r, j] = s * qri + c * qrj
        negative = False
        for i in range(k):
            if a[i, i] < 0.0:
                negative = True
        if not negative:
            continue
        changed += 1
        for i in range(k):
            for j in range(i, k):
                v = 0.0
                for e in range(k):
                    if a[e, e] > 0.0:
                        v += q[i, e] * a[e, e] * q[j, e]
                T[p, packed_index(i, j, k)] = v
    return changed


@njit(cache=True)
def release_reactions(v, g, mass, free, nodes, basis, count):
    """v_i <- v_i - (q.g_i) q / m_i on the nodes with one constrained direction q
    (`project`'s arguments): the velocity a node would have without its contact's
    reaction, which is the constrained component of the unprojected gradient
    g = M (v - v*) + dPhi/dv at the solution. The walls and colliders then act on it as in
    the explicit step: a push (into the obstacle) is removed again and takes Coulomb
    friction off the tangential part, a pull lets a separate contact go. Releasing pulls
    matters: keeping them held while pushes brake counts each elastic rebound as extra
    normal load (measured on a sliding block, Newton mode at cfl 0.05: deceleration
    1.19 mu g held, 1.003 released). Nodes with more constrained directions (sticky,
    prescribed, corners) are left alone: their directions are Gram-Schmidt combinations,
    not a contact normal the boundaries would remove again, and no tangent is free."""
    d = v.shape[1]
    for k in range(nodes.shape[0]):
        n = nodes[k]
        if count[k] != 1 or free[n] == 0.0 or mass[n] <= 0.0:
            continue
        s = 0.0
        for a in range(d):
            s += g[n, a] * basis[k, 0, a]
        s /= mass[n]
        for a in range(d):
            v[n, a] -= s * basis[k, 0, a]


@njit(cache=True)
def add_inertia(out, mass, u, target, free):
    """out_i += free_i m_i (u_i - target_i): the inertia term of the gradient of E
    (000 §3.4: E = 1/2 sum_i m_i |v_i - v*_i|^2 + sum_p e_p). Flat (N, d) and (N,) arrays."""
    d = out.shape[1]
    for n in range(out.shape[0]):
        if free[n] != 0.0:
            m = mass[n]
            for a in range(d):
                out[n, a] += m * (u[n, a] - target[n, a])


@njit(cache=True)
def add_mass_times(out, mass, u, free):
    """out_i += free_i m_i u_i: the inertia term of the Hessian-vector product."""
    d = out.shape[1]
    for n in range(out.shape[0]):
        if free[n] != 0.0:
            m = mass[n]
            for a in range(d):
                out[n, a] += m * u[n, a]


@njit(cache=True)
def multiply(a, b, out):
    """out <- a * b elementwise (flat arrays)."""
    for n in range(out.shape[0]):
        out[n] = a[n] * b[n]


# -- the unknowns alone ---------------------------------------------------------------------
# ``active`` lists the flat indices of the unknowns (owned nodes with mass) in increasing
# order. The CG's vectors are zero elsewhere on the owned nodes, and what the ghosts hold is
# never read before a fill, so its iterations need not sweep the whole block (an unknown is
# 19-49 % of a block's nodes in the shipped semi-implicit scenes). The index order is the
# order `owned_dot` visits the nodes in, so a sum over ``active`` is bitwise the block's.
@njit(cache=True)
def cg_update(active, first, alpha, beta, u, w, p, s, x, r, inverse):
    """One CG iteration's vector work on the unknowns, (N, d) arrays: p <- u + beta p and
    s <- w + beta s (p <- u, s <- w on the first), x <- x + alpha p, r <- r - alpha s, and
    the Jacobi step u <- inverse * r (its constraints: `constrain`)."""
    d = u.shape[1]
    for k in range(active.shape[0]):
        n = active[k]
        for a in range(d):
            if first:
                pa = u[n, a]
                sa = w[n, a]
            else:
                pa = u[n, a] + beta * p[n, a]
                sa = w[n, a] + beta * s[n, a]
            p[n, a] = pa
            s[n, a] = sa
            x[n, a] += alpha * pa
            r[n, a] -= alpha * sa
            u[n, a] = inverse[n, a] * r[n, a]


@njit(cache=True)
def residual_active(active, b, w, r):
    """r <- b - w on the unknowns."""
    d = r.shape[1]
    for k in range(active.shape[0]):
        n = active[k]
        for a in range(d):
            r[n, a] = b[n, a] - w[n, a]


@njit(cache=True)
def add_mass_times_active(out, mass, u, active):
    """out_i += m_i u_i on the unknowns (`add_mass_times`)."""
    d = out.shape[1]
    for k in range(active.shape[0]):
        n = active[k]
        m = mass[n]
        for a in range(d):
            out[n, a] += m * u[n, a]


@njit(cache=True)
def cg_dots(active, r, u, w):
    """(r.u, w.u, r.r) over the unknowns, each summed node by node as `owned_dot` does."""
    d = r.shape[1]
    ru = wu = rr = 0.0
    for k in range(active.shape[0]):
        n = active[k]
        s_ru = s_wu = s_rr = 0.0
        for a in range(d):
            s_ru += r[n, a] * u[n, a]
            s_wu += w[n, a] * u[n, a]
            s_rr += r[n, a] * r[n, a]
        ru += s_ru
        wu += s_wu
        rr += s_rr
    return ru, wu, rr


@njit(cache=True)
def inverse_diagonal(material, mass, free, out):
    """Jacobi: out_ia = 1 / (m_i + material_ia), the inverse diagonal of H on the unknowns
    (0 elsewhere); 1 / m_i where a non-convex material makes that sum non-positive (the mass
    is the part of the diagonal that is always there). material, out (N, d); mass, free (N,)."""
    d = out.shape[1]
    for n in range(out.shape[0]):
        for a in range(d):
            total = mass[n] + material[n, a]
            if free[n] == 0.0:
                out[n, a] = 0.0
            elif total > 0.0:
                out[n, a] = 1.0 / total
            else:
                out[n, a] = 1.0 / mass[n]


@njit(cache=True)
def stiffness_ratio(material, mass, free):
    """max over the unknowns of diag(H)_ia / m_i = (m_i + |material_ia|) / m_i: how far the
    stiffest node's diagonal stands above its inertia (1 for a body without stiffness; about
    (c dt / dx)^2 for a wave speed c). 1.0 when there are no unknowns."""
    d = material.shape[1]
    ratio = 1.0
    for n in range(material.shape[0]):
        if free[n] == 0.0:
            continue
        for a in range(d):
            r = (mass[n] + abs(material[n, a])) / mass[n]
            if r > ratio:
                ratio = r
    return ratio


@njit(cache=True)
def owned_dot(a, b, mass, power, lo, hi):
    """sum over the nodes of the index box [lo, hi) that have mass of m_i^power a_i . b_i
    (power 0, 1 or 2). a, b (n0, n1, n2, c) and mass (n0, n1, n2): a block viewed as 3D
    (n2 = 1 in 2D) with c components. The loop order is fixed: i, j, k, then components."""
    c = a.shape[3]
    total = 0.0
    for i in range(lo[0], hi[0]):
        for j in range(lo[1], hi[1]):
            for k in range(lo[2], hi[2]):
                m = mass[i, j, k]
                if m <= 0.0:
                    continue
                s = 0.0
                for q in range(c):
                    s += a[i, j, k, q] * b[i, j, k, q]
                if power == 1:
                    s *= m
                elif power == 2:
                    s *= m * m
                total += s
    return total

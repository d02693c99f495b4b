"""Small-strain linear elasticity (Hooke's law) written on the deformation gradient.

eps = sym(F) - I, psi = mu eps:eps + lam/2 tr(eps)^2, P = 2 mu eps + lam tr(eps) I
(the small-strain limit of every model here). Not rotation invariant: only for small rotations and
strains (verification problems, wave propagation). The 2D variant is plane strain.
"""

from __future__ import annotations

from numba import njit

from .base import ElasticMaterial
from .implicit import LINEAR, ImplicitF
from .tensors import load2, load3, mul2_bt, mul3_bt, store2, store3


@njit(cache=True)
def _stress_2d(F, tau, mu, lam):
    """tau_p = P(F_p) F_p^T for F, tau (n, 2, 2)."""
    for p in range(F.shape[0]):
        f = load2(F, p)
        e00 = f[0] - 1.0
        e11 = f[3] - 1.0
        e01 = 0.5 * (f[1] + f[2])
        tr = lam * (e00 + e11)
        P = (2.0 * mu * e00 + tr, 2.0 * mu * e01, 2.0 * mu * e01, 2.0 * mu * e11 + tr)
        store2(tau, p, mul2_bt(P, f))


@njit(cache=True)
def _stress_3d(F, tau, mu, lam):
    """tau_p = P(F_p) F_p^T for F, tau (n, 3, 3)."""
    for p in range(F.shape[0]):
        f = load3(F, p)
        e00 = f[0] - 1.0
        e11 = f[4] - 1.0
        e22 = f[8] - 1.0
        e01 = 0.5 * (f[1] + f[3])
        e02 = 0.5 * (f[2] + f[6])
        e12 = 0.5 * (f[5] + f[7])
        tr = lam * (e00 + e11 + e22)
        m2 = 2.0 * mu
        P = (m2 * e00 + tr, m2 * e01, m2 * e02,
             m2 * e01, m2 * e11 + tr, m2 * e12,
             m2 * e02, m2 * e12, m2 * e22 + tr)
        store3(tau, p, mul3_bt(P, f))


@njit(cache=True)
def _energy(F, vol0, mu, lam):
    """sum_p vol0_p psi(F_p) for F (n, d, d), either dimension (no tensor products)."""
    d = F.shape[1]
    total = 0.0
    for p in range(F.shape[0]):
        ee = 0.0
        tr = 0.0
        for i in range(d):
            tr += F[p, i, i] - 1.0
            for j in range(d):
                e = 0.5 * (F[p, i, j] + F[p, j, i]) - (1.0 if i == j else 0.0)
                ee += e * e
        total += vol0[p] * (mu * ee + 0.5 * lam * tr * tr)
    return total


class LinearElastic(ImplicitF, ElasticMaterial):
    """Hooke's law on eps = sym(F) - I; Kirchhoff stress tau = P F^T with
    P = 2 mu eps + lam tr(eps) I."""

    name = "linear_elastic"
    implicit_model = LINEAR
    stress_kernels = {2: _stress_2d, 3: _stress_3d}
    energy_kernels = {2: _energy, 3: _energy}

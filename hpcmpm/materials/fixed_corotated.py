"""Fixed corotated hyperelasticity (Stomakhin et al. 2012).

psi = mu ||F - R||_F^2 + lam/2 (J - 1)^2                             (003 eq. 3.5)
P = 2 mu (F - R) + lam (J - 1) J F^-T,  tau = P F^T = 2 mu (F - R) F^T + lam (J - 1) J I

R is the rotation of the polar decomposition F = R S (signed SVD convention, so R stays a
rotation and the energy stays finite and smooth through inversion). The kernels are shared
with the snow model, which evaluates them on F_E with hardened (mu, lam).
"""

from __future__ import annotations

from numba import njit

from .base import ElasticMaterial
from .decompositions import polar2, polar3
from .implicit import COROTATED, ImplicitF
from .tensors import det2, det3, load2, load3, mul2_bt, mul3_bt, store2, store3


@njit(cache=True, inline="always")
def corotated_tau_2d(f, R, mu, lam):
    """tau = 2 mu (F - R) F^T + lam (J - 1) J I for 2x2 tuples f, R."""
    J = det2(f)
    m2 = 2.0 * mu
    a = mul2_bt((m2 * (f[0] - R[0]), m2 * (f[1] - R[1]), m2 * (f[2] - R[2]), m2 * (f[3] - R[3])), f)
    pressure = lam * (J - 1.0) * J
    return (a[0] + pressure, a[1], a[2], a[3] + pressure)


@njit(cache=True)
def corotated_tau_3d(f, R, mu, lam):
    """tau = 2 mu (F - R) F^T + lam (J - 1) J I for 3x3 tuples f, R."""
    J = det3(f)
    m2 = 2.0 * mu
    D = (m2 * (f[0] - R[0]), m2 * (f[1] - R[1]), m2 * (f[2] - R[2]),
         m2 * (f[3] - R[3]), m2 * (f[4] - R[4]), m2 * (f[5] - R[5]),
         m2 * (f[6] - R[6]), m2 * (f[7] - R[7]), m2 * (f[8] - R[8]))
    a = mul3_bt(D, f)
    pressure = lam * (J - 1.0) * J
    return (a[0] + pressure, a[1], a[2], a[3], a[4] + pressure, a[5], a[6], a[7], a[8] + pressure)


@njit(cache=True)
def corotated_psi_2d(f, R, mu, lam):
    """mu ||F - R||^2 + lam/2 (J - 1)^2 for 2x2 tuples."""
    s = 0.0
    for k in range(4):
        s += (f[k] - R[k]) * (f[k] - R[k])
    J1 = det2(f) - 1.0
    return mu * s + 0.5 * lam * J1 * J1


@njit(cache=True)
def corotated_psi_3d(f, R, mu, lam):
    """mu ||F - R||^2 + lam/2 (J - 1)^2 for 3x3 tuples."""
    s = 0.0
    for k in range(9):
        s += (f[k] - R[k]) * (f[k] - R[k])
    J1 = det3(f) - 1.0
    return mu * s + 0.5 * lam * J1 * J1


@njit(cache=True)
def _stress_2d(F, tau, mu, lam):
    for p in range(F.shape[0]):
        f = load2(F, p)
        R, _ = polar2(f)
        store2(tau, p, corotated_tau_2d(f, R, mu, lam))


@njit(cache=True)
def _stress_3d(F, tau, mu, lam):
    for p in range(F.shape[0]):
        f = load3(F, p)
        R, _ = polar3(f)
        store3(tau, p, corotated_tau_3d(f, R, mu, lam))


@njit(cache=True)
def _energy_2d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load2(F, p)
        R, _ = polar2(f)
        total += vol0[p] * corotated_psi_2d(f, R, mu, lam)
    return total


@njit(cache=True)
def _energy_3d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load3(F, p)
        R, _ = polar3(f)
        total += vol0[p] * corotated_psi_3d(f, R, mu, lam)
    return total


class FixedCorotated(ImplicitF, ElasticMaterial):
    """Fixed corotated solid, 003 eq. 3.5 (Stomakhin 2012)."""

    name = "fixed_corotated"
    implicit_model = COROTATED
    stress_kernels = {2: _stress_2d, 3: _stress_3d}
    energy_kernels = {2: _energy_2d, 3: _energy_3d}

"""Compressible Neo-Hookean hyperelasticity (Bonet and Wood 1997).

psi = mu/2 (tr(F^T F) - d) - mu ln J + lam/2 (ln J)^2            (003 eq. 3.8)
tau = P F^T = mu (F F^T - I) + lam ln J I

This is the log-volume form of 003 eq. 3.8; 000 eq. 5.8/5.9 uses the same deviatoric part with
lam/2 (J - 1)^2 instead. Both reduce to Hooke's law with the same (mu, lam) at small strain;
the log form resists full compression without bound (psi -> inf as J -> 0). d is the dimension
(plane strain in 2D).
"""

from __future__ import annotations

import math

from numba import njit

from .base import ElasticMaterial
from .implicit import NEO_HOOKEAN, ImplicitF
from .tensors import det2, det3, frob2, frob3, load2, load3, mul2_bt, mul3_bt, store2, store3


@njit(cache=True)
def _stress_2d(F, tau, mu, lam):
    """tau_p = mu (F F^T - I) + lam ln J I for F, tau (n, 2, 2)."""
    for p in range(F.shape[0]):
        f = load2(F, p)
        b = mul2_bt(f, f)
        pressure = lam * math.log(det2(f))
        store2(tau, p, (mu * (b[0] - 1.0) + pressure, mu * b[1],
                        mu * b[2], mu * (b[3] - 1.0) + pressure))


@njit(cache=True)
def _stress_3d(F, tau, mu, lam):
    """tau_p = mu (F F^T - I) + lam ln J I for F, tau (n, 3, 3)."""
    for p in range(F.shape[0]):
        f = load3(F, p)
        b = mul3_bt(f, f)
        pressure = lam * math.log(det3(f))
        store3(tau, p, (mu * (b[0] - 1.0) + pressure, mu * b[1], mu * b[2],
                        mu * b[3], mu * (b[4] - 1.0) + pressure, mu * b[5],
                        mu * b[6], mu * b[7], mu * (b[8] - 1.0) + pressure))


@njit(cache=True)
def _energy_2d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load2(F, p)
        log_j = math.log(det2(f))
        total += vol0[p] * (0.5 * mu * (frob2(f) - 2.0) - mu * log_j + 0.5 * lam * log_j * log_j)
    return total


@njit(cache=True)
def _energy_3d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load3(F, p)
        log_j = math.log(det3(f))
        total += vol0[p] * (0.5 * mu * (frob3(f) - 3.0) - mu * log_j + 0.5 * lam * log_j * log_j)
    return total


class NeoHookean(ImplicitF, ElasticMaterial):
    """Compressible Neo-Hookean solid, 003 eq. 3.8; needs det F > 0."""

    name = "neo_hookean"
    implicit_model = NEO_HOOKEAN
    stress_kernels = {2: _stress_2d, 3: _stress_3d}
    energy_kernels = {2: _energy_2d, 3: _energy_3d}

"""Stable Neo-Hookean hyperelasticity (Smith, de Goes and Kim 2018).

psi = mu/2 (I_C - d) + lam/2 (J - alpha)^2 - mu/2 ln(I_C + 1)          (003 eq. 7.1)
P   = mu (1 - 1/(I_C + 1)) F + lam (J - alpha) J F^-T                  (003 eq. 7.2)

with I_C = tr(F^T F) and d the dimension. Rest stability fixes alpha: at F = I, I_C = d and
P = [mu d/(d+1) + lam (1 - alpha)] I = 0 gives

    alpha = 1 + (d/(d+1)) mu/lam,

which is Smith's 1 + mu/lam - mu/(4 lam) = 1 + 3/4 mu/lam in 3D (the garbled "mu lam/4" of
003 below eq. 7.1 is this term) and 1 + 2/3 mu/lam in 2D. The code never forms alpha (it
would divide by lam = 0 at nu = 0): with c0 = d/(d+1), lam (J - alpha) = lam (J - 1) - c0 mu,
so

    tau = P F^T = mu I_C/(I_C + 1) F F^T + (lam (J - 1) - c0 mu) J I,

which is exactly zero at F = I in floating point (I_C/(I_C+1) and d/(d+1) round the same way).
The energy is shifted by the constant psi(I), so the rest state has zero energy:

    psi = mu/2 (I_C - d) + lam/2 (J - 1)^2 - c0 mu (J - 1) - mu/2 ln((I_C + 1)/(d + 1)).

Lamé reparameterisation (Smith et al. 2018, §3.4). Linearising P at F = I + H gives
P ~ mu d/(d+1) (H + H^T) + [lam + mu (2 - d(d+1))/(d+1)^2] tr(H) I, so (mu, lam) of the
energy are not the small-strain moduli. We take E, nu as the small-strain (linear elastic)
moduli mu_LE, lam_LE, as Smith do, and use in the energy

    mu = (d+1)/d mu_LE,   lam = lam_LE + (d(d+1) - 2)/(d(d+1)) mu_LE

(3D: mu = 4/3 mu_LE, lam = lam_LE + 5/6 mu_LE, Smith's values; 2D: 3/2 and 2/3). Then the
model has the same small-strain response, and the same wave speed sqrt((lam_LE + 2 mu_LE)/rho),
as every other model given the same E, nu.
"""

from __future__ import annotations

import math

from numba import njit

from .base import ElasticMaterial
from .implicit import STABLE_NH, ImplicitF
from .tensors import det2, det3, frob2, frob3, load2, load3, mul2_bt, mul3_bt, store2, store3


@njit(cache=True)
def _stress_2d(F, tau, mu, lam):
    """tau_p (n, 2, 2) from F_p (n, 2, 2); mu, lam are the energy's (reparameterised) moduli."""
    c0 = 2.0 / 3.0
    for p in range(F.shape[0]):
        f = load2(F, p)
        J = det2(f)
        ic = frob2(f)
        m = mu * (ic / (ic + 1.0))
        b = mul2_bt(f, f)
        pressure = (lam * (J - 1.0) - mu * c0) * J
        store2(tau, p, (m * b[0] + pressure, m * b[1], m * b[2], m * b[3] + pressure))


@njit(cache=True)
def _stress_3d(F, tau, mu, lam):
    """tau_p (n, 3, 3) from F_p (n, 3, 3); mu, lam are the energy's (reparameterised) moduli."""
    c0 = 3.0 / 4.0
    for p in range(F.shape[0]):
        f = load3(F, p)
        J = det3(f)
        ic = frob3(f)
        m = mu * (ic / (ic + 1.0))
        b = mul3_bt(f, f)
        pressure = (lam * (J - 1.0) - mu * c0) * J
        store3(tau, p, (m * b[0] + pressure, m * b[1], m * b[2],
                        m * b[3], m * b[4] + pressure, m * b[5],
                        m * b[6], m * b[7], m * b[8] + pressure))


@njit(cache=True)
def _psi(ic, J, d, mu, lam):
    """Energy density (shifted to psi(I) = 0) from I_C and J."""
    c0 = d / (d + 1.0)
    return (0.5 * mu * (ic - d) + 0.5 * lam * (J - 1.0) * (J - 1.0) - c0 * mu * (J - 1.0)
            - 0.5 * mu * math.log1p((ic - d) / (d + 1.0)))


@njit(cache=True)
def _energy_2d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load2(F, p)
        total += vol0[p] * _psi(frob2(f), det2(f), 2.0, mu, lam)
    return total


@njit(cache=True)
def _energy_3d(F, vol0, mu, lam):
    total = 0.0
    for p in range(F.shape[0]):
        f = load3(F, p)
        total += vol0[p] * _psi(frob3(f), det3(f), 3.0, mu, lam)
    return total


class StableNeoHookean(ImplicitF, ElasticMaterial):
    """Stable Neo-Hookean solid, 003 eq. 7.1-7.2 (Smith 2018); defined for any F, inverted
    included. self.mu, self.lam are the small-strain moduli (wave speed); the kernels get the
    reparameterised pair of the energy (module docstring)."""

    name = "stable_neo_hookean"
    implicit_model = STABLE_NH
    stress_kernels = {2: _stress_2d, 3: _stress_3d}
    energy_kernels = {2: _energy_2d, 3: _energy_3d}

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        d = float(dim)
        self.mu_energy = (d + 1.0) / d * self.mu
        self.lam_energy = self.lam + (d * (d + 1.0) - 2.0) / (d * (d + 1.0)) * self.mu

    def kernel_moduli(self) -> tuple[float, float]:
        return self.mu_energy, self.lam_energy

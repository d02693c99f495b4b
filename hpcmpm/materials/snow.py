"""Snow: fixed corotated elasticity on F_E with singular-value clamping and hardening.

Stomakhin et al. 2013; 000 §4.4-4.5; 003 §3.3.3. After each F update the trial elastic part
F_E = U Sigma V^T (signed SVD) has its singular values clamped to [1 - theta_c, 1 + theta_s];
the excess goes into the plastic part:

    F_E <- U Sigma_c V^T,   F_P <- V Sigma_c^-1 U^T F_E^trial F_P = V Sigma_c^-1 Sigma V^T F_P,

so F_E F_P (the total deformation gradient) is unchanged. The Lamé parameters harden with
plastic compression,

    mu = mu0 h,  lam = lam0 h,  h = exp(min(xi (1 - J_P), max_exponent)),     (000 §4.5.1)

and the stress is the fixed corotated one (003 eq. 3.5) of F_E with (mu, lam).

Storage (Stomakhin's convention): the particle field ``F`` holds F_E after the projection,
``Fp`` holds F_P and ``Jp`` holds det F_P, so the total deformation gradient is ``F @ Fp``. The
grid-to-particle update F <- (I + dt grad v) F therefore advances the trial F_E, as it must;
the projection follows at once (`return_map`, run by the step right after G2P), so frames and
checkpoints hold the projected state. The stress kernel recomputes the polar rotation of the
projected F_E (one more decomposition per particle than a fused clamp-and-stress kernel, the
price of a state that is projected between steps).
`energy` is the elastic energy of F_E with the hardened moduli.

Softening (000 §4.5.2, Ram's modification): xi < 0 makes mu, lam *decrease* under plastic
compression (J_P < 1): h = exp(-|xi| (1 - J_P)) falls towards exp(-|xi|) > 0, so the material
never loses all stiffness. With xi < 0 plastic *extension* (J_P > 1) stiffens it instead, and
there xi (1 - J_P) grows without bound; ``max_exponent`` caps the exponent so exp() cannot
overflow. Its default, |xi|, never binds for hardening (xi > 0 gives xi (1 - J_P) < xi for any
J_P > 0) and for softening bounds the stiffening by the same factor exp(|xi|).

`wave_speed` reports the rest value sqrt((lam0 + 2 mu0)/rho); `max_wave_speed`, which the
explicit time step reads (a maximum over the ranks), the hardened one: hardening multiplies both
moduli by h, so the P-wave speed by sqrt(h), up to exp(max_exponent / 2). With the rest value
alone, a block of snow (xi = 10) compacted by an impact reached h = 54 within 17 steps, a
Courant number c dt / dx of 1.2, and blew up.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..state import SCALAR, TENSOR, FieldSpec
from .base import Material
from .decompositions import v_diag_vt, polar2, polar3, svd2, svd3
from .failure import SPB_FAILURE
from .implicit import COROTATED, ImplicitF
from .params import POISSON, YOUNG, Param, lame
from .fixed_corotated import corotated_psi_2d, corotated_psi_3d, corotated_tau_2d, corotated_tau_3d
from .tensors import load2, load3, mul2, mul2_bt, mul3, mul3_bt, store2, store3


@njit(cache=True)
def _clamp(s, lo, hi):
    return min(max(s, lo), hi)


@njit(cache=True)
def hardening(Jp, xi, max_exponent):
    """h = exp(min(xi (1 - Jp), max_exponent)), the factor on mu0 and lam0 (000 §4.5)."""
    return math.exp(min(xi * (1.0 - Jp), max_exponent))


@njit(cache=True)
def largest_hardening(Jp, xi, max_exponent):
    """max(1, max_p h(Jp_p)): the factor on the rest moduli that bounds the wave speed (a
    softened particle is not taken below the rest value)."""
    top = 1.0
    for p in range(Jp.shape[0]):
        top = max(top, hardening(Jp[p], xi, max_exponent))
    return top


@njit(cache=True)
def _project_2d(F, Fp, Jp, lo, hi):
    """Clamp F_E = F[p], move the excess into Fp[p] and Jp[p].
    F, Fp (n, 2, 2); Jp (n,). lo, hi: the clamp interval of the singular values."""
    for p in range(F.shape[0]):
        U, s0, s1, V = svd2(load2(F, p))
        c0 = _clamp(s0, lo, hi)
        c1 = _clamp(s1, lo, hi)
        if c0 != s0 or c1 != s1:
            r0 = s0 / c0
            r1 = s1 / c1
            # V diag(r) V^T
            M = (V[0] * V[0] * r0 + V[1] * V[1] * r1, V[0] * V[2] * r0 + V[1] * V[3] * r1,
                 V[2] * V[0] * r0 + V[3] * V[1] * r1, V[2] * V[2] * r0 + V[3] * V[3] * r1)
            store2(Fp, p, mul2(M, load2(Fp, p)))
            Jp[p] *= r0 * r1
            store2(F, p, mul2_bt((U[0] * c0, U[1] * c1, U[2] * c0, U[3] * c1), V))


@njit(cache=True)
def _project_3d(F, Fp, Jp, lo, hi):
    """Clamp F_E = F[p], move the excess into Fp[p] and Jp[p].
    F, Fp (n, 3, 3); Jp (n,). lo, hi: the clamp interval of the singular values."""
    for p in range(F.shape[0]):
        U, s0, s1, s2, V = svd3(load3(F, p))
        c0 = _clamp(s0, lo, hi)
        c1 = _clamp(s1, lo, hi)
        c2 = _clamp(s2, lo, hi)
        if c0 != s0 or c1 != s1 or c2 != s2:
            r0 = s0 / c0
            r1 = s1 / c1
            r2 = s2 / c2
            store3(Fp, p, mul3(v_diag_vt(V, r0, r1, r2), load3(Fp, p)))
            Jp[p] *= r0 * r1 * r2
            store3(F, p, mul3_bt((U[0] * c0, U[1] * c1, U[2] * c2,
                                  U[3] * c0, U[4] * c1, U[5] * c2,
                                  U[6] * c0, U[7] * c1, U[8] * c2), V))


@njit(cache=True)
def _stress_2d(F, Jp, tau, mu0, lam0, xi, max_exponent):
    """Fixed corotated tau of the (projected) F_E with the hardened moduli; F, tau (n, 2, 2)."""
    for p in range(F.shape[0]):
        f = load2(F, p)
        R, _ = polar2(f)
        h = hardening(Jp[p], xi, max_exponent)
        store2(tau, p, corotated_tau_2d(f, R, mu0 * h, lam0 * h))


@njit(cache=True)
def _stress_3d(F, Jp, tau, mu0, lam0, xi, max_exponent):
    """Fixed corotated tau of the (projected) F_E with the hardened moduli; F, tau (n, 3, 3)."""
    for p in range(F.shape[0]):
        f = load3(F, p)
        R, _ = polar3(f)
        h = hardening(Jp[p], xi, max_exponent)
        store3(tau, p, corotated_tau_3d(f, R, mu0 * h, lam0 * h))


@njit(cache=True)
def _energy_2d(F, Jp, vol0, mu0, lam0, xi, max_exponent):
    total = 0.0
    for p in range(F.shape[0]):
        f = load2(F, p)
        R, _ = polar2(f)
        h = hardening(Jp[p], xi, max_exponent)
        total += vol0[p] * corotated_psi_2d(f, R, mu0 * h, lam0 * h)
    return total


@njit(cache=True)
def _energy_3d(F, Jp, vol0, mu0, lam0, xi, max_exponent):
    total = 0.0
    for p in range(F.shape[0]):
        f = load3(F, p)
        R, _ = polar3(f)
        h = hardening(Jp[p], xi, max_exponent)
        total += vol0[p] * corotated_psi_3d(f, R, mu0 * h, lam0 * h)
    return total


@njit(cache=True)
def times_inverse(A, B, out):
    """out_p = A_p B_p^-1 for (n, d, d) stacks, d = 2 or 3 (snow's F_E = F^PD F_P^-1)."""
    d = A.shape[1]
    for p in range(A.shape[0]):
        if d == 2:
            det = B[p, 0, 0] * B[p, 1, 1] - B[p, 0, 1] * B[p, 1, 0]
            i00, i01 = B[p, 1, 1] / det, -B[p, 0, 1] / det
            i10, i11 = -B[p, 1, 0] / det, B[p, 0, 0] / det
            for r in range(2):
                a0, a1 = A[p, r, 0], A[p, r, 1]
                out[p, r, 0] = a0 * i00 + a1 * i10
                out[p, r, 1] = a0 * i01 + a1 * i11
        else:
            c00 = B[p, 1, 1] * B[p, 2, 2] - B[p, 1, 2] * B[p, 2, 1]
            c01 = B[p, 1, 2] * B[p, 2, 0] - B[p, 1, 0] * B[p, 2, 2]
            c02 = B[p, 1, 0] * B[p, 2, 1] - B[p, 1, 1] * B[p, 2, 0]
            det = B[p, 0, 0] * c00 + B[p, 0, 1] * c01 + B[p, 0, 2] * c02
            inv = ((c00 / det, (B[p, 0, 2] * B[p, 2, 1] - B[p, 0, 1] * B[p, 2, 2]) / det,
                    (B[p, 0, 1] * B[p, 1, 2] - B[p, 0, 2] * B[p, 1, 1]) / det),
                   (c01 / det, (B[p, 0, 0] * B[p, 2, 2] - B[p, 0, 2] * B[p, 2, 0]) / det,
                    (B[p, 0, 2] * B[p, 1, 0] - B[p, 0, 0] * B[p, 1, 2]) / det),
                   (c02 / det, (B[p, 0, 1] * B[p, 2, 0] - B[p, 0, 0] * B[p, 2, 1]) / det,
                    (B[p, 0, 0] * B[p, 1, 1] - B[p, 0, 1] * B[p, 1, 0]) / det))
            for r in range(3):
                for c in range(3):
                    out[p, r, c] = (A[p, r, 0] * inv[0][c] + A[p, r, 1] * inv[1][c]
                                    + A[p, r, 2] * inv[2][c])


class Snow(ImplicitF, Material):
    """Stomakhin 2013 snow: clamped fixed corotated elasticity with (de)hardening; F holds F_E."""

    name = "snow"
    parameters = {
        "E": YOUNG,
        "nu": POISSON,
        "theta_c": Param(0.0, 1.0, low_inclusive=True,
                         doc="critical compression: singular values of F_E >= 1 - theta_c "
                             "(Stomakhin: 2.5e-2)"),
        "theta_s": Param(0.0, math.inf, low_inclusive=True,
                         doc="critical stretch: singular values of F_E <= 1 + theta_s "
                             "(Stomakhin: 7.5e-3)"),
        "xi": Param(-math.inf, math.inf,
                    doc="hardening coefficient (Stomakhin: 10); < 0 softens under plastic "
                        "compression (000 §4.5.2)"),
        "max_exponent": Param(0.0, 700.0, required=False, default=None, low_inclusive=True,
                              doc="cap on xi (1 - Jp) in the hardening factor so exp() stays "
                                  "finite; default |xi|"),
        "failure": SPB_FAILURE,
    }
    fields = {"Fp": FieldSpec(TENSOR, "f8", "identity"), "Jp": FieldSpec(SCALAR, "f8", 1.0)}
    implicit_model = COROTATED  # elastic at the current F_E; the clamp acts after the solve

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        q = self.params
        self.mu, self.lam = lame(q["E"], q["nu"])
        self.lower = 1.0 - q["theta_c"]
        self.upper = 1.0 + q["theta_s"]
        self.xi = q["xi"]
        self.max_exponent = abs(self.xi) if q["max_exponent"] is None else q["max_exponent"]
        self._project = _project_2d if dim == 2 else _project_3d
        self._stress = _stress_2d if dim == 2 else _stress_3d
        self._energy = _energy_2d if dim == 2 else _energy_3d

    def implicit_moduli(self, fields) -> tuple:
        """(mu0, lam0, Jp, xi, max_exponent): the kernels harden per particle."""
        return self.mu, self.lam, fields["Jp"], self.xi, self.max_exponent

    def hardening(self, Jp: float) -> float:
        """The factor h(Jp) on mu0 and lam0."""
        return float(hardening(Jp, self.xi, self.max_exponent))

    def max_wave_speed(self, fields) -> float:
        """The P-wave speed at the largest hardening of these particles, sqrt(h) times the
        rest value (000 §4.5: mu = mu0 h, lam = lam0 h)."""
        return self.wave_speed() * math.sqrt(
            largest_hardening(np.ascontiguousarray(fields["Jp"]), self.xi, self.max_exponent))

    def return_map(self, fields, dt: float) -> None:
        """Projects fields["F"] (n, d, d, the trial F_E G2P advanced) onto the clamp and
        moves the excess into fields["Fp"] (n, d, d) and fields["Jp"] (n,)."""
        self._project(fields["F"], fields["Fp"], fields["Jp"], self.lower, self.upper)

    def update_stress(self, fields, dt: float) -> None:
        """Writes fields["tau"] (n, d, d) from the projected F_E and the hardening of Jp."""
        self._stress(fields["F"], fields["Jp"], fields["tau"], self.mu, self.lam, self.xi,
                     self.max_exponent)

    def pd_stress(self, fields, F, tau) -> None:
        """tau (k, d, d) at the peridynamic deformation gradients F (SPB-MPM,
        `failure.pd_stress`): the elastic part F_E = F^PD F_P^-1 with the hardening of Jp."""
        FE = np.empty_like(F)
        times_inverse(F, np.ascontiguousarray(fields["Fp"]), FE)
        self._stress(FE, np.ascontiguousarray(fields["Jp"]), tau, self.mu, self.lam, self.xi,
                     self.max_exponent)

    def energy(self, fields) -> float:
        """sum_p vol0_p psi_FC(F_E,p; mu(Jp), lam(Jp))."""
        return float(self._energy(fields["F"], fields["Jp"], fields["vol0"], self.mu, self.lam,
                                  self.xi, self.max_exponent))

"""Semi-implicit energy, gradient and Hessian-vector product of the F-based models, in terms of
the step's velocity gradient L (HELPERS item 3; 000 §3.4, §5.5; Stomakhin 2013 §4; Gast 2015).

With the state F^n of t^n held fixed and F_hat = (I + dt L) F^n (000 eq. 5.12):

    e(L)      = V0 psi(F_hat)
    de/dL     = dt V0 P(F_hat) F^n^T
    D^2e[dL]  = dt^2 V0 dP(F_hat)[dL F^n] F^n^T

so at L = 0, de/dL = dt V0 P(F^n) F^n^T = dt V0 tau^n: the grid force
f_i = -sum_p (de_p/dL_p) grad w_ip / dt is the explicit one. Each model supplies psi, P and
dP = D P(F)[dF] below (one generic kernel per phase, the model picked by an integer code; the
dimension by the witness tuple, `hpcmpm.materials.matrix`):

    LINEAR       psi = mu eps:eps + lam/2 tr(eps)^2, eps = sym F - I; P = 2 mu eps + lam tr(eps) I
    COROTATED    psi = mu |F - R|^2 + lam/2 (J - 1)^2; P = 2 mu (F - R) + lam (J - 1) cof F,
                 dP = 2 mu (dF - dR) + lam (cof F : dF) cof F + lam (J - 1) Dcof(F)[dF],
                 dR = R Omega with Omega S + S Omega = R^T dF - dF^T R (F = R S; closed form:
                 2D omega = (R^T dF)_10 - (R^T dF)_01 over tr S; 3D axial vector
                 (tr S I - S)^-1 x). Snow uses it on F_E with hardened moduli.
    NEO_HOOKEAN  psi = mu/2 (I_C - d) - mu ln J + lam/2 (ln J)^2; P = mu (F - F^-T) + lam ln J F^-T
    STABLE_NH    003 eq. 7.1-7.2 shifted (stable_neo_hookean.py); P = mu (1 - 1/(I_C + 1)) F
                 + (lam (J - 1) - c0 mu) cof F, c0 = d/(d+1)

and the J-only fluid psi(J) = E (J - 1 - ln J) (weakly_compressible.py) has its own kernels
(`j_energy`, ...), since its state may be J alone. The plastic projections of snow act after the
solve (in update_state), so its energy is elastic at the current F_E.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload

from .decompositions import polar2, polar3
from .matrix import (add, add_identity, axpy, cofactor, dcofactor, ddot, det, dim_of, inverse,
                     load, mul, mul_bt, scale, store, sub, sym, trace, transpose)

LINEAR, COROTATED, NEO_HOOKEAN, STABLE_NH = 0, 1, 2, 3
NO_HARDENING = np.empty(0)  # ``Jp`` of a model without snow's hardening

# dR is undefined where two signed singular values sum to zero (an inverted F_hat); the floor
# keeps the Hessian finite there (the line search rejects such states anyway).
MIN_ROTATION_DENOMINATOR = 1e-12


def polar_parts(f):
    """(R, S) of F = R S (`polar2` / `polar3` by size). Compiled code only."""
    raise NotImplementedError("numba-only helper")


@overload(polar_parts)
def _polar_parts(f):
    if f.count == 4:
        return lambda f: polar2(f)
    if f.count == 9:
        return lambda f: polar3(f)


def rotation_derivative(R, S, dF):
    """dR of F = R S in direction dF (module docstring). Compiled code only."""
    raise NotImplementedError("numba-only helper")


def _rotation_derivative2(R, S, dF):
    M = mul(transpose(R), dF)
    den = S[0] + S[3]
    den = den if abs(den) > MIN_ROTATION_DENOMINATOR else MIN_ROTATION_DENOMINATOR
    w = (M[2] - M[1]) / den
    return mul(R, (0.0, -w, w, 0.0))


def _rotation_derivative3(R, S, dF):
    M = mul(transpose(R), dF)
    x0 = M[7] - M[5]
    x1 = M[2] - M[6]
    x2 = M[3] - M[1]
    A = add_identity(scale(-1.0, S), S[0] + S[4] + S[8])  # (tr S I - S) w = x
    a = det(A)
    a = a if abs(a) > MIN_ROTATION_DENOMINATOR else MIN_ROTATION_DENOMINATOR
    C = cofactor(A)  # A symmetric: A^-1 = C / det A
    w0 = (C[0] * x0 + C[1] * x1 + C[2] * x2) / a
    w1 = (C[3] * x0 + C[4] * x1 + C[5] * x2) / a
    w2 = (C[6] * x0 + C[7] * x1 + C[8] * x2) / a
    return mul(R, (0.0, -w2, w1, w2, 0.0, -w0, -w1, w0, 0.0))


@overload(rotation_derivative)
def _rotation_derivative(R, S, dF):
    if R.count == 4:
        return _rotation_derivative2
    if R.count == 9:
        return _rotation_derivative3


@njit(cache=True)
def psi_point(model, F, mu, lam):
    """Energy density psi(F); +inf where the model is undefined (J <= 0 for Neo-Hookean)."""
    d = dim_of(F)
    if model == LINEAR:
        eps = add_identity(sym(F), -1.0)
        tr = trace(eps)
        return mu * ddot(eps, eps) + 0.5 * lam * tr * tr
    J = det(F)
    if model == COROTATED:
        R, _ = polar_parts(F)
        D = sub(F, R)
        return mu * ddot(D, D) + 0.5 * lam * (J - 1.0) * (J - 1.0)
    ic = ddot(F, F)
    if model == NEO_HOOKEAN:
        if not J > 0.0:
            return math.inf
        lj = math.log(J)
        return 0.5 * mu * (ic - d) - mu * lj + 0.5 * lam * lj * lj
    c0 = d / (d + 1.0)
    return (0.5 * mu * (ic - d) + 0.5 * lam * (J - 1.0) * (J - 1.0) - c0 * mu * (J - 1.0)
            - 0.5 * mu * math.log1p((ic - d) / (d + 1.0)))


@njit(cache=True)
def piola_point(model, F, mu, lam):
    """First Piola-Kirchhoff stress P = dpsi/dF."""
    d = dim_of(F)
    if model == LINEAR:
        eps = add_identity(sym(F), -1.0)
        return add_identity(scale(2.0 * mu, eps), lam * trace(eps))
    J = det(F)
    C = cofactor(F)
    if model == COROTATED:
        R, _ = polar_parts(F)
        return axpy(lam * (J - 1.0), C, scale(2.0 * mu, sub(F, R)))
    if model == NEO_HOOKEAN:
        FiT = scale(1.0 / J, C)
        return axpy(lam * math.log(J), FiT, scale(mu, sub(F, FiT)))
    ic = ddot(F, F)
    c0 = d / (d + 1.0)
    return axpy(lam * (J - 1.0) - c0 * mu, C, scale(mu * (1.0 - 1.0 / (ic + 1.0)), F))


@njit(cache=True)
def dpiola_point(model, F, dF, mu, lam):
    """dP = D P(F)[dF] (module docstring)."""
    d = dim_of(F)
    if model == LINEAR:
        return add_identity(scale(2.0 * mu, sym(dF)), lam * trace(dF))
    J = det(F)
    C = cofactor(F)
    dC = dcofactor(F, dF)
    dJ = ddot(C, dF)
    if model == COROTATED:
        R, S = polar_parts(F)
        dR = rotation_derivative(R, S, dF)
        return add(scale(2.0 * mu, sub(dF, dR)), axpy(lam * dJ, C, scale(lam * (J - 1.0), dC)))
    if model == NEO_HOOKEAN:
        FiT = scale(1.0 / J, C)
        # mu dF + (mu - lam ln J) F^-T dF^T F^-T + lam tr(F^-1 dF) F^-T
        return add(axpy(mu - lam * math.log(J), mul(mul_bt(FiT, dF), FiT), scale(mu, dF)),
                   scale(lam * dJ / J, FiT))
    ic = ddot(F, F)
    c0 = d / (d + 1.0)
    k = ic + 1.0
    dev = axpy(2.0 * mu * ddot(F, dF) / (k * k), F, scale(mu * (1.0 - 1.0 / k), dF))
    return add(dev, axpy(lam * dJ, C, scale(lam * (J - 1.0) - c0 * mu, dC)))


@njit(cache=True)
def _hardening(Jp, p, xi, max_exponent):
    """Snow's factor on (mu, lam) (000 §4.5); 1 when the model has no hardening (Jp empty)."""
    if Jp.shape[0] == 0:
        return 1.0
    return math.exp(min(xi * (1.0 - Jp[p]), max_exponent))


@njit(cache=True)
def f_energy(eye, model, F, vol0, Lv, dt, mu, lam, Jp, xi, max_exponent):
    """sum_p V0 psi((I + dt L_p) F_p); +inf as soon as one particle is inadmissible
    (det F_hat <= 0 for every model but linear elasticity)."""
    total = 0.0
    for p in range(F.shape[0]):
        Fh = mul(axpy(dt, load(Lv, p, eye), eye), load(F, p, eye))
        if model != LINEAR and not det(Fh) > 0.0:
            return math.inf
        h = _hardening(Jp, p, xi, max_exponent)
        total += vol0[p] * psi_point(model, Fh, mu * h, lam * h)
    return total


@njit(cache=True)
def f_gradient(eye, model, F, vol0, Lv, dt, mu, lam, Jp, xi, max_exponent, G):
    """G_p = dt V0 P(F_hat_p) F_p^T (n, d, d)."""
    for p in range(F.shape[0]):
        Fn = load(F, p, eye)
        Fh = mul(axpy(dt, load(Lv, p, eye), eye), Fn)
        h = _hardening(Jp, p, xi, max_exponent)
        store(G, p, scale(dt * vol0[p], mul_bt(piola_point(model, Fh, mu * h, lam * h), Fn)))


@njit(cache=True)
def f_hessian(eye, model, F, vol0, Lv, dt, mu, lam, Jp, xi, max_exponent, dLv, dG):
    """dG_p = dt^2 V0 dP(F_hat_p)[dL_p F_p] F_p^T (n, d, d)."""
    for p in range(F.shape[0]):
        Fn = load(F, p, eye)
        Fh = mul(axpy(dt, load(Lv, p, eye), eye), Fn)
        dF = mul(load(dLv, p, eye), Fn)
        h = _hardening(Jp, p, xi, max_exponent)
        store(dG, p, scale(dt * dt * vol0[p],
                           mul_bt(dpiola_point(model, Fh, dF, mu * h, lam * h), Fn)))


# -- the J-only fluid: psi(J) = E (J - 1 - ln J) ----------------------------------------------
@njit(cache=True)
def j_energy(eye, J, vol0, Lv, dt, E):
    """sum_p V0 psi(J_p det(I + dt L_p)); +inf if a J_hat <= 0."""
    total = 0.0
    for p in range(J.shape[0]):
        Jh = J[p] * det(axpy(dt, load(Lv, p, eye), eye))
        if not Jh > 0.0:
            return math.inf
        total += vol0[p] * E * (Jh - 1.0 - math.log(Jh))
    return total


@njit(cache=True)
def j_gradient(eye, J, vol0, Lv, dt, E, G):
    """G_p = dt V0 E (J_hat - 1) A^-T, A = I + dt L_p."""
    for p in range(J.shape[0]):
        A = axpy(dt, load(Lv, p, eye), eye)
        Jh = J[p] * det(A)
        store(G, p, scale(dt * vol0[p] * E * (Jh - 1.0), transpose(inverse(A))))


@njit(cache=True)
def j_hessian(eye, J, vol0, Lv, dt, E, dLv, dG):
    """dG_p = dt^2 V0 E [J_hat (A^-T : D) A^-T - (J_hat - 1) A^-T D^T A^-T]."""
    for p in range(J.shape[0]):
        A = axpy(dt, load(Lv, p, eye), eye)
        D = load(dLv, p, eye)
        Jh = J[p] * det(A)
        AiT = transpose(inverse(A))
        dG_p = axpy(Jh * ddot(AiT, D), AiT, scale(1.0 - Jh, mul(mul_bt(AiT, D), AiT)))
        store(dG, p, scale(dt * dt * vol0[p] * E, dG_p))


class ImplicitF:
    """Mixin: the semi-implicit hooks of an F-based model (HELPERS item 3), from the model's
    integer code ``implicit_model`` and `implicit_moduli`. ``fields["F"]`` must hold F^n (the
    state at t^n: call these before update_state advances it)."""

    implicit = True
    implicit_model: int = LINEAR

    def implicit_moduli(self, fields) -> tuple:
        """(mu, lam, Jp, xi, max_exponent) for the kernels; Jp empty: no hardening."""
        mu, lam = self.kernel_moduli()
        return mu, lam, NO_HARDENING, 0.0, 0.0

    def implicit_energy(self, fields, L, dt: float) -> float:
        """sum_p V0_p psi((I + dt L_p) F_p^n); +inf when a particle is inadmissible."""
        F = fields["F"]
        return float(f_energy(_eye(F), self.implicit_model, F, fields["vol0"], L, dt,
                              *self.implicit_moduli(fields)))

    def implicit_gradient(self, fields, L, dt: float, G) -> None:
        """Writes G (n, d, d), G_p = de_p/dL_p = dt V0_p P(F_hat_p) F_p^n^T."""
        F = fields["F"]
        f_gradient(_eye(F), self.implicit_model, F, fields["vol0"], L, dt,
                   *self.implicit_moduli(fields), G)

    def implicit_hessian(self, fields, L, dt: float, dL, dG) -> None:
        """Writes dG (n, d, d), dG_p = D^2 e_p(L_p)[dL_p]."""
        F = fields["F"]
        f_hessian(_eye(F), self.implicit_model, F, fields["vol0"], L, dt,
                  *self.implicit_moduli(fields), dL, dG)


def _eye(A) -> tuple:
    from .matrix import EYE
    return EYE[A.shape[-1]]

"""Elastoplasticity on the elastic left Cauchy-Green strain b_E: Oldroyd-B, Herschel-Bulkley and
von Mises (000 ch. 4-6, appendix A; Ram 2015), as numba kernels written once for 2D and 3D.

State per particle: ``b`` (n, d, d) and ``J`` (n,), the volume ratio det F; the ``fe`` plastic
updates also carry ``Fe`` (n, d, d) and ``fe_bdf2`` carries ``Fe_prev`` too.

One step, L the step's velocity gradient (000 eq. 5.12-5.14, §4.6-4.7, §6.1.4):

    J^{n+1} = det(I + dt L) J^n                                          (000 eq. 5.12)
    b_hat(L) = S + dt (L R + R^T L^T) + dt^2 L B L^T                     (S, R, B from t^n)
    b_E = (J^2 / det b_hat)^(1/d) b_hat                                   (000 eq. 5.5, 5.13)
    psi = mu/2 (tr b_E - d) - mu ln J + lam/2 (J - 1)^2                  (000 eq. 5.8)
    tau = J sigma_E = mu (b_E - I) + lam (J - 1) J I                      (000 eq. 5.9)

with S, R, B per plastic update (a = 1/(1 + dt/Wi), r = dt/Wi):

    OB_EXPLICIT (eq. 5.14)  S = r I + (1 - r) b^n, R = b^n, B = 0
    OB_SPD (§4.6.1)         S = a (r I + b^n), R = B = a b^n
    FE (§4.7.1)             K = F_E + (r/2)(F_E^-T - F_E); S = K K^T, R = F_E K^T, B = F_E F_E^T
    FE_BDF2 (§6.1.4)        q = 3 + r, K = [4 F_E^n - F_E^n-1 + r (2 F_E^-T,n - F_E^-T,n-1)] / q,
                            M = 2 (2 F_E^n - F_E^n-1) / q; S = K K^T, R = M K^T, B = M M^T
                            (first step, F_E^n-1 unset, by FE)
    HB (§4.6.2, §4.2.5)     gdot = max(0, (|dev b^n| - sigma_Y)/eta)^(1/h),
                            alpha = (2 dt/d) tr b^n gdot / |dev b^n|, beta = tr b^n / d,
                            c = 1/(1 + alpha); S = c (b^n + alpha beta I), R = B = c b^n
    VM (§4.2.6, §4.3)       trial S = R = B = b^n (elastic predictor, Wi = inf), then radial
                            return of dev(b_bar), b_bar = b / det(b)^(1/d), to |dev b_bar| <= sigma_Y
                            (Simo 1988), trace kept

The fe updates are exactly F_E^{n+1} = K + dt L M with b_hat = F_E^{n+1} (F_E^{n+1})^T.

What is stored. Oldroyd-B stores the *unscaled* conformation b_OB (000 §5.5: "we store b_OB^n
on each particle"; b_E = (J/J_OB)^(2/d) b_OB only enters psi and tau), so the stored b of a
homogeneous flow is the classic Oldroyd-B conformation A and the stress uses c A with
c = (J^2/det A)^(1/d). Herschel-Bulkley and von Mises store the rescaled b (det b = J^2) and
evaluate the flow rule on it: the literal §4.6.2 never rescales, so det b grows without bound in
steady shear and the stress keeps falling; with the rescale the steady shear stress is
tau_y + K gdot^h, tau_y = mu sigma_Y / sqrt(2), K = mu eta 2^(-(h+1)/2) (small-strain limit,
issue 9). The 3D constants of the print (2/3, -3, (2/3) tr) are 2/d, -d, (2/d) tr here.

Newtonian viscosity (000 eq. 5.10-5.11, corrected): potential dt mu_N eps:eps V^n with
eps = sym L and V^n = V0 J^n, so sigma_N = 2 mu_N eps and tau_N = 2 mu_N J eps. The print's
eq. 5.11 and A.1 lack the factor dt (units), and §5.4's (mu_N/2)(grad v + grad v^T) is half
what the potential gives.

Semi-implicit energy (HELPERS item 3; 000 appendix A, rederived in terms of L):
e_p(L) = V0 psi(b_E(L), J(L)) + dt V0 J^n mu_N eps:eps, and with A = I + dt L,
W = R^T + dt L B, q = (J^2/det b_hat)^(1/d), t = tr b_hat, T = q t, Kb = b_hat^-1 W,
c1 = (mu/d) T - mu + lam (J - 1) J:

    de/dL = dt V0 [c1 A^-T + mu q (W - (t/d) Kb)] + 2 dt V0 J^n mu_N eps.

At L = 0 with S = R (Wi = inf, any plasticity but fe_bdf2, or HB below yield) this is
dt V0 tau(b^n, J^n): the grid force f_i = -sum_p (de_p/dL) grad w_ip / dt is the eq. 5.9
force. The Hessian-vector product is the directional derivative of that expression (see
`_hessian_point`). No SVD anywhere: determinants and inverses are closed forms.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numba import njit

from ..state import SCALAR, TENSOR, FieldSpec
from ..errors import SceneError
from ..kernels.tangent import packed_index
from .base import Material
from . import isochoric_return as implicit_return
from .matrix import (EYE, add, add_identity, axpy, ddot, det, dim_of, inverse, load, mul,
                     mul_bt, root_d, scale, store, sub, sym, trace, transpose)
from .params import POISSON, YOUNG, MATERIAL_TABLE_KEYS, Param, check_params, choice, lame

OB_EXPLICIT, OB_SPD, FE, FE_BDF2, HB, VM = 0, 1, 2, 3, 4, 5
# Implicit isochoric return (isochoric_return.py): Herschel-Bulkley, and von Mises with eta = 0.
HB_IMPLICIT = 6
# mu = 0 (a compressible Newtonian fluid): the conformation enters neither the stress nor the
# energy, so it is not advanced (b stays I; S = I, R = B = 0). Advanced, it grows without
# bound under steady shear (tr b ~ shear strain^2) until det b_hat is lost to round-off: the
# Newtonian channel stopped as "inadmissible" at t = 25.7 (shear strain ~130 at the walls).
FLUID = 7
PLASTICITY_MODES = {"ob_spd": OB_SPD, "ob_explicit": OB_EXPLICIT, "fe": FE, "fe_bdf2": FE_BDF2}

# Keys every b_E model accepts: the moduli as (mu, lambda) or (E, nu), and the viscosity.
ELASTIC_KEYS = {
    "mu": Param(0.0, math.inf, required=False, low_inclusive=True,
                doc="shear modulus mu (stress units), 0 allowed (a Newtonian fluid); give mu "
                    "and lambda, or E and nu"),
    "lambda": Param(0.0, math.inf, required=False, low_inclusive=True,
                    doc="Lame's first parameter lambda (stress units)"),
    "E": YOUNG._replace(required=False),
    "nu": POISSON._replace(required=False),
    "viscosity": Param(0.0, math.inf, required=False, default=0.0, low_inclusive=True,
                       doc="Newtonian viscosity mu_N (dynamic: stress x time); "
                           "sigma_N = 2 mu_N sym(grad v)"),
}

# The viscoplastic models' (HB, von Mises) plastic update: "implicit" the variational return of
# isochoric_return.py (force = stress of the returned state, consistent tangent; 2D),
# "explicit" the b_hat with the flow evaluated at t^n, "auto" implicit under the
# semi-implicit integrator in 2D and explicit otherwise (the explicit integrator's verified
# results keep their update).
FLOW_UPDATE = choice(("auto", "implicit", "explicit"), "auto",
                     doc="plastic update: implicit (end-of-step return, variational, 2D), "
                         "explicit (000 §4.6.2 with the flow at t^n), auto (implicit for the "
                         "semi-implicit integrator in 2D, else explicit)")


# -- per-particle pieces ---------------------------------------------------------------------
@njit(cache=True)
def fe_factors(mode, f, fp, r):
    """(K, M) of the fe updates, F_E^{n+1} = K + dt L M (000 §4.7.1, §6.1.4); r = dt/Wi.
    fe_bdf2 falls back to fe while F_E^{n-1} is unset (zero: det 0)."""
    fit = transpose(inverse(f))
    if mode == FE_BDF2 and det(fp) != 0.0:
        q = 3.0 + r
        fpit = transpose(inverse(fp))
        K = scale(1.0 / q, add(sub(scale(4.0, f), fp), scale(r, sub(scale(2.0, fit), fpit))))
        M = scale(2.0 / q, sub(scale(2.0, f), fp))
        return K, M
    return axpy(0.5 * r, sub(fit, f), f), f


@njit(cache=True)
def plastic_factors(mode, b, f, fp, dt, inv_wi, sigma_y, inv_h, eta):
    """(S, R, B) of b_hat(L) = S + dt (L R + R^T L^T) + dt^2 L B L^T from the state at t^n
    (module docstring). b: b^n; f, fp: F_E^n, F_E^{n-1} (read by the fe modes only)."""
    r = dt * inv_wi
    if mode == FLUID:
        zero = scale(0.0, b)
        return add_identity(zero, 1.0), zero, zero
    if mode == OB_EXPLICIT:
        return add_identity(scale(1.0 - r, b), r), b, scale(0.0, b)
    if mode == OB_SPD:
        a = 1.0 / (1.0 + r)
        R = scale(a, b)
        return scale(a, add_identity(b, r)), R, R
    if mode == FE or mode == FE_BDF2:
        K, M = fe_factors(mode, f, fp, r)
        return mul_bt(K, K), mul_bt(M, K), mul_bt(M, M)
    if mode == HB:
        d = dim_of(b)
        tr = trace(b)
        beta = tr / d
        D = add_identity(b, -beta)
        n = math.sqrt(ddot(D, D))
        alpha = 0.0
        if n > sigma_y:  # n > 0 too, since sigma_y >= 0
            gdot = ((n - sigma_y) / eta) ** inv_h
            alpha = (2.0 * dt / d) * tr * gdot / n
        c = 1.0 / (1.0 + alpha)
        R = scale(c, b)
        return scale(c, add_identity(b, alpha * beta)), R, R
    return b, b, b  # VM: elastic trial


@njit(cache=True)
def b_hat(S, R, B, L, dt):
    """S + dt (L R + R^T L^T) + dt^2 L B L^T, exactly symmetric."""
    LR = mul(L, R)
    return sym(add(add(S, scale(dt, add(LR, transpose(LR)))), scale(dt * dt, mul_bt(mul(L, B), L))))


@njit(cache=True)
def radial_return(bh, sigma_y):
    """von Mises return (Simo 1988) on the isochoric b_bar = bh / det(bh)^(1/d): dev b_bar
    scaled back to |dev b_bar| = sigma_Y when it lies outside, tr b_bar kept. Returns b_bar
    (the caller rescales det to J^2)."""
    bbar = scale(1.0 / root_d(bh, det(bh)), bh)
    beta = trace(bbar) / dim_of(bh)
    D = add_identity(bbar, -beta)
    n = math.sqrt(ddot(D, D))
    if n > sigma_y:
        return add_identity(scale(sigma_y / n, D), beta)
    return bbar


@njit(cache=True)
def admissible(J, h, t):
    """J > 0, det b_hat > 0 and tr b_hat > 0 (false for NaN too)."""
    return J > 0.0 and h > 0.0 and t > 0.0


@njit(cache=True)
def kirchhoff(b, J, mu, lam):
    """tau = mu (b_E - I) + lam (J - 1) J I with b_E = (J^2/det b)^(1/d) b (000 eq. 5.9)."""
    bE = scale(root_d(b, J * J / det(b)), b)
    return add_identity(scale(mu, bE), lam * (J - 1.0) * J - mu)


@njit(cache=True)
def psi(b, J, mu, lam):
    """000 eq. 5.8 at b_E = (J^2/det b)^(1/d) b; +inf when inadmissible."""
    h = det(b)
    t = trace(b)
    if not admissible(J, h, t):
        return math.inf
    T = root_d(b, J * J / h) * t
    return 0.5 * mu * (T - dim_of(b)) - mu * math.log(J) + 0.5 * lam * (J - 1.0) * (J - 1.0)


@njit(cache=True)
def _gradient_parts(S, R, B, L, dt, Jn, mu, lam):
    """Intermediates shared by the gradient and the Hessian (module docstring)."""
    eye = add_identity(scale(0.0, L), 1.0)
    A = axpy(dt, L, eye)
    J = Jn * det(A)
    AiT = transpose(inverse(A))
    bh = b_hat(S, R, B, L, dt)
    h = det(bh)
    t = trace(bh)
    d = dim_of(L)
    q = root_d(L, J * J / h)
    bhi = inverse(bh)
    W = add(transpose(R), scale(dt, mul(L, B)))
    Kb = mul(bhi, W)
    c1 = (mu / d) * q * t - mu + lam * (J - 1.0) * J
    return J, AiT, bh, bhi, h, t, q, W, Kb, c1


@njit(cache=True)
def _gradient_point(S, R, B, L, dt, Jn, mu, lam):
    """(de_E/dL) / (dt V0) and admissibility."""
    J, AiT, bh, bhi, h, t, q, W, Kb, c1 = _gradient_parts(S, R, B, L, dt, Jn, mu, lam)
    ok = admissible(J, h, t)
    d = dim_of(L)
    G = add(scale(c1, AiT), scale(mu * q, sub(W, scale(t / d, Kb))))
    return G, ok


@njit(cache=True)
def _hessian_point(S, R, B, L, D, dt, Jn, mu, lam):
    """D^2 e_E[D] / (dt V0): the derivative of `_gradient_point` in the direction D."""
    return _hessian_from_parts(_gradient_parts(S, R, B, L, dt, Jn, mu, lam), B, D, dt, mu,
                               lam)


@njit(cache=True)
def _hessian_from_parts(parts, B, D, dt, mu, lam):
    """`_hessian_point` from the `_gradient_parts` of its point and its B (shared by the
    directions of a tangent)."""
    J, AiT, bh, bhi, h, t, q, W, Kb, c1 = parts
    d = dim_of(D)
    j1 = ddot(AiT, D)                               # tr(A^-1 D)
    dJ = J * dt * j1
    WDt = mul_bt(W, D)
    dbh = scale(dt, add(WDt, transpose(WDt)))       # dt (D W^T + W D^T)
    k1 = 2.0 * ddot(Kb, D)                          # tr(b_hat^-1 dbh) / dt
    dq = q * dt * ((2.0 / d) * j1 - k1 / d)
    dtr = 2.0 * dt * ddot(W, D)                     # tr dbh
    dc1 = (mu / d) * (dq * t + q * dtr) + lam * (2.0 * J - 1.0) * dJ
    dAiT = scale(-dt, mul(mul_bt(AiT, D), AiT))     # -dt A^-T D^T A^-T
    dW = scale(dt, mul(D, B))
    dKb = mul(bhi, sub(dW, mul(dbh, Kb)))
    dG = add(add(scale(dc1, AiT), scale(c1, dAiT)),
             add(scale(mu * dq, sub(W, scale(t / d, Kb))),
                 scale(mu * q, sub(sub(dW, scale(dtr / d, Kb)), scale(t / d, dKb)))))
    return dG


# -- kernels over a material's particle slice ------------------------------------------------
@njit(cache=True)
def update_state(eye, mode, b, J, Fe, Fe_prev, Lv, dt, inv_wi, sigma_y, inv_h, eta, rescale,
                 decrements, known):
    """Advance b (n, d, d), J (n,) and, for the fe modes, Fe (and Fe_prev) over dt with the
    step's velocity gradient Lv (n, d, d). ``rescale``: store b with det b = J^2 (HB, VM) or
    the unscaled conformation (Oldroyd-B). An inadmissible particle (J, det b_hat or tr b_hat
    <= 0) gets J = NaN and keeps its b. Returns (count of such particles, first index, its J,
    det b_hat, tr b_hat). HB_IMPLICIT with ``known``: the returns' decrements at these L
    are in ``decrements`` (n,)."""
    bad = 0
    first = -1
    fJ = fh = ft = 0.0
    for p in range(b.shape[0]):
        L = load(Lv, p, eye)
        bn = load(b, p, eye)
        Jnew = J[p] * det(axpy(dt, L, eye))
        if mode == FE or mode == FE_BDF2:
            f = load(Fe, p, eye)
            K, M = fe_factors(mode, f, load(Fe_prev, p, eye), dt * inv_wi)
            fnew = add(K, scale(dt, mul(L, M)))
            bh = mul_bt(fnew, fnew)
            if admissible(Jnew, det(bh), trace(bh)):
                if mode == FE_BDF2:
                    store(Fe_prev, p, f)
                store(Fe, p, fnew)
        elif mode == HB_IMPLICIT:  # b_E with det J^2 already: the rescale is round-off
            Delta = decrements[p] if known else implicit_return.decrement(
                bn, L, dt, J[p], sigma_y, 1.0 / inv_h, eta)
            bh, Jnew, _, _, _ = implicit_return.returned(bn, L, dt, J[p], Delta)
        else:
            S, R, B = plastic_factors(mode, bn, bn, bn, dt, inv_wi, sigma_y, inv_h, eta)
            bh = b_hat(S, R, B, L, dt)
            if mode == VM:
                bh = radial_return(bh, sigma_y)
        h = det(bh)
        t = trace(bh)
        if not admissible(Jnew, h, t):
            if bad == 0:
                first, fJ, fh, ft = p, Jnew, h, t
            bad += 1
            J[p] = math.nan
            continue
        if rescale:
            bh = scale(root_d(bh, Jnew * Jnew / h), bh)
        store(b, p, bh)
        J[p] = Jnew
    return bad, first, fJ, fh, ft


@njit(cache=True)
def stress(eye, b, J, Lv, tau, mu, lam, mu_n):
    """tau_p = mu (b_E - I) + lam (J - 1) J I + 2 mu_N J sym(L_p) (000 eq. 5.9; viscous part
    from the stored L of the last step; mu_n = 0 skips it and Lv is not read)."""
    for p in range(b.shape[0]):
        Jp = J[p]
        t = kirchhoff(load(b, p, eye), Jp, mu, lam)
        if mu_n != 0.0:
            t = axpy(2.0 * mu_n * Jp, sym(load(Lv, p, eye)), t)
        store(tau, p, t)


@njit(cache=True)
def elastic_strain(eye, b, J, bE):
    """bE_p = (J_p^2 / det b_p)^(1/d) b_p, the b_E of the stress."""
    for p in range(b.shape[0]):
        bp = load(b, p, eye)
        store(bE, p, scale(root_d(bp, J[p] * J[p] / det(bp)), bp))


@njit(cache=True)
def energy(eye, b, J, vol0, mu, lam):
    """sum_p vol0_p psi(b_p, J_p) (000 eq. 5.8); +inf if a particle is inadmissible."""
    total = 0.0
    for p in range(b.shape[0]):
        total += vol0[p] * psi(load(b, p, eye), J[p], mu, lam)
    return total


@njit(cache=True)
def implicit_energy(eye, mode, b, J, Fe, Fe_prev, vol0, Lv, dt, mu, lam, mu_n, inv_wi, sigma_y,
                    inv_h, eta, decrements, known):
    """sum_p e_p(L_p) with the state at t^n fixed; +inf as soon as one particle is
    inadmissible. HB_IMPLICIT: ``known``, the returns' decrements at these L are in
    ``decrements`` (n,); else the kernel solves them and writes them there."""
    total = 0.0
    for p in range(b.shape[0]):
        L = load(Lv, p, eye)
        if mode == HB_IMPLICIT:
            if known:
                e = implicit_return.energy_density(load(b, p, eye), L, dt, J[p], mu, lam,
                                                      sigma_y, 1.0 / inv_h, eta, decrements[p])
            else:
                e, decrements[p] = implicit_return.energy_and_decrement(
                    load(b, p, eye), L, dt, J[p], mu, lam, sigma_y, 1.0 / inv_h, eta)
        else:
            S, R, B = plastic_factors(mode, load(b, p, eye), load(Fe, p, eye),
                                      load(Fe_prev, p, eye), dt, inv_wi, sigma_y, inv_h, eta)
            e = psi(b_hat(S, R, B, L, dt), J[p] * det(axpy(dt, L, eye)), mu, lam)
        if e == math.inf:
            return math.inf
        eps = sym(L)
        total += vol0[p] * (e + dt * J[p] * mu_n * ddot(eps, eps))
    return total


@njit(cache=True)
def implicit_gradient(eye, mode, b, J, Fe, Fe_prev, vol0, Lv, dt, mu, lam, mu_n, inv_wi,
                      sigma_y, inv_h, eta, G, decrements, known):
    """G_p = de_p/dL_p (n, d, d). Returns the number of inadmissible particles (their G is
    NaN). HB_IMPLICIT: ``known``, the returns' decrements at these L are in ``decrements``
    (n,); else the kernel solves them and writes them there."""
    bad = 0
    for p in range(b.shape[0]):
        L = load(Lv, p, eye)
        if mode == HB_IMPLICIT:
            bn = load(b, p, eye)
            if not known:
                decrements[p] = implicit_return.decrement(bn, L, dt, J[p], sigma_y,
                                                          1.0 / inv_h, eta)
            g, ok = implicit_return.gradient_point(bn, L, dt, J[p], mu, lam, decrements[p])
        else:
            S, R, B = plastic_factors(mode, load(b, p, eye), load(Fe, p, eye),
                                      load(Fe_prev, p, eye), dt, inv_wi, sigma_y, inv_h, eta)
            g, ok = _gradient_point(S, R, B, L, dt, J[p], mu, lam)
        if not ok:
            bad += 1
            g = scale(math.nan, g)
        w = dt * vol0[p]
        store(G, p, axpy(2.0 * mu_n * J[p] * w, sym(L), scale(w, g)))
    return bad


@njit(cache=True)
def return_decrements(eye, b, J, Lv, dt, sigma_y, inv_h, eta, out):
    """out_p = Delta_p, the implicit return's plastic decrement at L_p (HB_IMPLICIT)."""
    for p in range(b.shape[0]):
        out[p] = implicit_return.decrement(load(b, p, eye), load(Lv, p, eye), dt, J[p],
                                           sigma_y, 1.0 / inv_h, eta)


@njit(cache=True)
def implicit_hessian(eye, mode, b, J, Fe, Fe_prev, vol0, Lv, dt, mu, lam, mu_n, inv_wi,
                     sigma_y, inv_h, eta, dLv, dG, decrements):
    """dG_p = D^2 e_p[dL_p] (n, d, d), the Hessian of e_p at L_p applied to dL_p.
    ``decrements``: HB_IMPLICIT's Delta_p at L_p (`return_decrements`; not read otherwise)."""
    for p in range(b.shape[0]):
        L = load(Lv, p, eye)
        D = load(dLv, p, eye)
        if mode == HB_IMPLICIT:
            hD = implicit_return.hessian_point(load(b, p, eye), L, D, dt, J[p], mu, lam, sigma_y,
                                               1.0 / inv_h, eta, decrements[p])
        else:
            S, R, B = plastic_factors(mode, load(b, p, eye), load(Fe, p, eye),
                                      load(Fe_prev, p, eye), dt, inv_wi, sigma_y, inv_h, eta)
            hD = _hessian_point(S, R, B, L, D, dt, J[p], mu, lam)
        w = dt * vol0[p]
        store(dG, p, axpy(2.0 * mu_n * J[p] * w, sym(D), scale(w, hD)))


@njit(cache=True)
def implicit_tangent(eye, mode, b, J, Fe, Fe_prev, vol0, Lv, dt, mu, lam, mu_n, inv_wi,
                     sigma_y, inv_h, eta, units, T, decrements):
    """T_p[:, k] = D^2 e_p(L_p)[E_k] for the d^2 unit directions E_k (``units`` (d^2, d, d)),
    its entries on and above the diagonal, packed (kernels/tangent.py): `implicit_hessian`
    for each E_k in one pass, the plastic factors and b_hat's parts computed once per
    particle instead of once per direction (the same arithmetic, tested)."""
    nk = units.shape[0]
    for p in range(b.shape[0]):
        L = load(Lv, p, eye)
        w = dt * vol0[p]
        wv = 2.0 * mu_n * J[p] * w
        if mode == HB_IMPLICIT:
            bn = load(b, p, eye)
            for k in range(nk):
                D = load(units, k, eye)
                hD = implicit_return.hessian_point(bn, L, D, dt, J[p], mu, lam, sigma_y,
                                                   1.0 / inv_h, eta, decrements[p])
                g = axpy(wv, sym(D), scale(w, hD))
                for r in range(k + 1):
                    T[p, packed_index(r, k, nk)] = g[r]
        else:
            S, R, B = plastic_factors(mode, load(b, p, eye), load(Fe, p, eye),
                                      load(Fe_prev, p, eye), dt, inv_wi, sigma_y, inv_h, eta)
            parts = _gradient_parts(S, R, B, L, dt, J[p], mu, lam)
            for k in range(nk):
                D = load(units, k, eye)
                g = axpy(wv, sym(D), scale(w, _hessian_from_parts(parts, B, D, dt, mu, lam)))
                for r in range(k + 1):
                    T[p, packed_index(r, k, nk)] = g[r]


_NO_DECREMENTS = np.zeros(0)
UNIT_DIRECTIONS = {d: np.eye(d * d).reshape(d * d, d, d) for d in (2, 3)}


# -- the material classes' common part -------------------------------------------------------
class LeftCauchyGreenMaterial(Material):
    """A b_E-based elastoplastic model (module docstring): deformation mode "L", state b and
    J (plus Fe, Fe_prev for the fe updates), Newtonian viscosity, the semi-implicit hooks.

    Subclasses set ``mode`` (or pick it in __init__), ``rescale_state`` and their extra keys,
    and fill ``self.inv_wi``, ``self.sigma_y``, ``self.inv_h``, ``self.eta``.
    """

    deformation: ClassVar[str] = "L"
    implicit: ClassVar[bool] = True
    parameters = ELASTIC_KEYS
    # The fields every instance has; an instance's own ``fields`` adds Fe (and Fe_prev) for the
    # fe updates, so the engine must read an instance's.
    fields = {"b": FieldSpec(TENSOR, "f8", "identity"), "J": FieldSpec(SCALAR, "f8", 1.0)}
    mode: ClassVar[int] = OB_SPD
    rescale_state: ClassVar[bool] = False

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        q = self.params
        if q["mu"] is not None:
            self.mu, self.lam = q["mu"], q["lambda"]
        else:
            self.mu, self.lam = lame(q["E"], q["nu"])
        self.viscosity = q["viscosity"]
        self.eye = EYE[dim]
        self._decrement_key = None
        self._decrement_values = _NO_DECREMENTS
        self.inv_wi, self.sigma_y, self.inv_h, self.eta = 0.0, 0.0, 1.0, 1.0
        # Per instance: the fe updates add their own fields.
        self.fields = dict(type(self).fields)

    @classmethod
    def parameter_problems(cls, params: dict[str, Any]) -> list[str]:
        """The schema check plus "mu and lambda, or E and nu" (one pair, both keys)."""
        problems = check_params(cls.parameters, params, MATERIAL_TABLE_KEYS)
        lame_pair = [k for k in ("mu", "lambda") if k in params]
        young_pair = [k for k in ("E", "nu") if k in params]
        if lame_pair and young_pair:
            problems.append(f"{young_pair[0]}: give mu and lambda, or E and nu, not both")
        elif not lame_pair and not young_pair:
            problems.append("mu: missing (give mu and lambda, or E and nu)")
        else:
            pair = ("mu", "lambda") if lame_pair else ("E", "nu")
            for k in pair:
                if k not in params:
                    problems.append(f"{k}: missing (given with {pair[0] if k == pair[1] else pair[1]})")
            if lame_pair == ["mu", "lambda"] and not problems and \
                    float(params["mu"]) == 0.0 and float(params["lambda"]) == 0.0:
                problems.append("lambda: mu and lambda are both 0: the material resists nothing")
        return problems

    # -- the viscoplastic update (HB, von Mises) ---------------------------------------------
    explicit_mode: ClassVar[int] = OB_SPD

    def _init_flow_update(self) -> None:
        """Reads ``flow_update``; "auto" starts explicit and `configure` decides."""
        self.flow_update = self.params["flow_update"]
        if self.flow_update == "implicit" and self.dim != 2:
            raise SceneError([f"material {self.spec.name!r} ({self.name}): flow_update: "
                              f"'implicit' is built for 2D only (the 3D return needs the "
                              f"principal log strains); use 'explicit' or 'auto'"])
        self._set_flow_update(self.flow_update == "implicit")

    def _set_flow_update(self, implicit: bool) -> None:
        self.mode = HB_IMPLICIT if implicit else self.explicit_mode
        self.implicit_eta = self.eta if self.explicit_mode == HB else 0.0

    def flow_update_problems(self, scene) -> list[str]:
        """Resolves "auto" against the scene's integrator and dimension (no problems: the
        constructor refuses 'implicit' in 3D)."""
        if self.flow_update == "auto":
            self._set_flow_update(getattr(scene, "integrator", "explicit") == "semi_implicit"
                                  and self.dim == 2)
        return []

    def notes(self) -> list[str]:
        """Which plastic update ``flow_update = "auto"`` chose for this scene."""
        if self.params.get("flow_update") != "auto":
            return []
        chosen = ("implicit (the end-of-step variational return: the semi-implicit integrator "
                  "in 2D)" if self.mode == HB_IMPLICIT else "explicit (000 §4.6.2, the flow "
                  "at t^n)")
        return [f"material {self.spec.name!r}: flow_update = \"auto\" runs {chosen}"]

    def dt_limit(self, dx: float) -> float:
        """Explicit viscous limit rho dx^2 / (2 d mu_N) (unbounded without viscosity)."""
        if self.viscosity == 0.0:
            return math.inf
        return self.density * dx * dx / (2.0 * self.dim * self.viscosity)

    def largest_time_step(self, scene) -> float:
        """An upper bound of the scene's time step: its fixed dt, else its max_dt and, for the
        explicit integrator, this material's own CFL and viscous bounds (the scene's dt is
        below both); inf for the semi-implicit integrator without max_dt (advection bound)."""
        if scene.dt is not None:
            return scene.dt
        bound = scene.max_dt if scene.max_dt is not None else math.inf
        if getattr(scene, "integrator", "explicit") == "explicit":
            c = self.wave_speed()
            if c > 0.0:
                bound = min(bound, scene.cfl * scene.dx / c)
            bound = min(bound, self.dt_limit(scene.dx))
        return bound

    def run_problems(self, scene) -> list[str]:
        """Problems ("key: what is wrong") of this material in ``scene`` (none here; Oldroyd-B
        checks its relaxation update against the time step and the integrator)."""
        return []

    def averages_volume(self, deformation: str) -> bool:
        """J is state apart from b: its grid average keeps b_E = (J^2/det b)^(1/d) b (the
        stress, the energy and the isochoric return read b only through its shape)."""
        return True

    def configure(self, scene) -> None:
        """Raises SceneError, one line per problem as "{file}: materials[i].key: ...", when
        this material cannot run in ``scene`` (`run_problems`)."""
        problems = self.run_problems(scene)
        if problems:
            where = f"materials[{scene.material_index(self.spec.name)}]"
            prefix = f"{scene.path}: " if getattr(scene, "path", None) else ""
            raise SceneError([f"{prefix}{where}.{p}" for p in problems])

    # -- state ------------------------------------------------------------------------------
    def _state(self, fields):
        b = fields["b"]
        Fe = fields.get("Fe", b)  # the kernels read Fe, Fe_prev in the fe modes only
        return b, fields["J"], Fe, fields.get("Fe_prev", Fe)

    def _plastic_args(self):
        if self.mode == HB_IMPLICIT:
            return self.inv_wi, self.sigma_y, self.inv_h, self.implicit_eta
        return self.inv_wi, self.sigma_y, self.inv_h, self.eta

    def update_state(self, fields, dt: float) -> None:
        """Advances b, J (and Fe, Fe_prev) over dt with the step's fields["L"] (n, d, d). A
        particle whose J, det b_hat or tr b_hat is not positive gets J = NaN and a line in
        ``self.failures``."""
        b, J, Fe, Fe_prev = self._state(fields)
        # The solve's last energy was often at this very L (APIC: G2P's L is the solve's to
        # the bit; MLS differs in round-off): then its returns need not be solved again.
        known = self._known_decrements(fields, fields["L"], dt)
        bad, first, fJ, fh, ft = update_state(self.eye, self.mode, b, J, Fe, Fe_prev,
                                              fields["L"], dt, *self._plastic_args(),
                                              self.rescale_state,
                                              _NO_DECREMENTS if known is None else known,
                                              known is not None)
        if bad:
            pid = int(fields["id"][first]) if "id" in fields else first
            more = f" ({bad - 1} more particles)" if bad > 1 else ""
            self.failures.append(
                f"material {self.spec.name!r} ({self.name}): particle id {pid}: inadmissible "
                f"elastic strain after the step: J = {fJ:.6g}, det b_hat = {fh:.6g}, "
                f"tr b_hat = {ft:.6g}{more}")

    def update_stress(self, fields, dt: float) -> None:
        """Writes fields["tau"] (n, d, d) = mu (b_E - I) + lam (J - 1) J I + 2 mu_N J sym(L)
        from the state and the stored fields["L"] (not read when viscosity = 0)."""
        b = fields["b"]
        Lv = fields["L"] if self.viscosity != 0.0 else b
        stress(self.eye, b, fields["J"], Lv, fields["tau"], self.mu, self.lam, self.viscosity)

    def energy(self, fields) -> float:
        """sum_p vol0_p psi(b_E,p, J_p) (000 eq. 5.8)."""
        return float(energy(self.eye, fields["b"], fields["J"], fields["vol0"], self.mu,
                            self.lam))

    def elastic_strain(self, fields) -> np.ndarray:
        """b_E = (J^2/det b)^(1/d) b per particle (n, d, d): the strain of the stress."""
        bE = np.empty_like(fields["b"])
        elastic_strain(self.eye, fields["b"], fields["J"], bE)
        return bE

    # -- semi-implicit hooks (HELPERS item 3) ---------------------------------------------------
    def _implicit_args(self, fields):
        b, J, Fe, Fe_prev = self._state(fields)
        return (self.eye, self.mode, b, J, Fe, Fe_prev, fields["vol0"])

    def _moduli(self):
        return (self.mu, self.lam, self.viscosity) + self._plastic_args()

    def implicit_energy(self, fields, L, dt: float) -> float:
        """sum_p e_p(L_p), e_p = V0 psi(b_E(L), J(L)) + dt V0 J^n mu_N sym(L):sym(L), with the
        state at t^n in ``fields``; +inf when a J, det b_hat or tr b_hat is not positive."""
        values, known = self._decrement_slots(fields, L, dt)
        energy = float(implicit_energy(*self._implicit_args(fields), L, dt, *self._moduli(),
                                       values, known))
        if not known and self.mode == HB_IMPLICIT and energy < math.inf:
            # Newton's line search ends at the point whose gradient comes next.
            self._remember_decrements(fields, L, dt, values)
        return energy

    def implicit_gradient(self, fields, L, dt: float, G) -> None:
        """Writes G (n, d, d), G_p = de_p/dL_p (energy x time; NaN where inadmissible)."""
        values, known = self._decrement_slots(fields, L, dt)
        implicit_gradient(*self._implicit_args(fields), L, dt, *self._moduli(), G, values,
                          known)
        if not known and self.mode == HB_IMPLICIT:
            self._remember_decrements(fields, L, dt, values)

    def implicit_hessian(self, fields, L, dt: float, dL, dG) -> None:
        """Writes dG (n, d, d), dG_p = D^2 e_p(L_p)[dL_p]."""
        implicit_hessian(*self._implicit_args(fields), L, dt, *self._moduli(), dL, dG,
                         self._decrements(fields, L, dt))

    def implicit_tangent(self, fields, L, dt: float, dL, dG, T) -> None:
        """Writes T packed (n, d^2 (d^2 + 1) / 2) in one pass (`implicit_tangent`); dL, dG
        unused."""
        implicit_tangent(*self._implicit_args(fields), L, dt, *self._moduli(),
                         UNIT_DIRECTIONS[L.shape[-1]], T, self._decrements(fields, L, dt))

    def _decrements(self, fields, L, dt: float) -> np.ndarray:
        """The implicit return's Delta_p at (state, L, dt), kept while those stay the same:
        the CG iterations of a Newton step apply the Hessian at one L many times, and the
        scalar Newton solve of the return is most of a product's cost. Empty outside
        HB_IMPLICIT."""
        if self.mode != HB_IMPLICIT:
            return _NO_DECREMENTS
        known = self._known_decrements(fields, L, dt)
        if known is not None:
            return known
        values = np.empty(len(L))
        return_decrements(self.eye, fields["b"], fields["J"], L, dt, self.sigma_y, self.inv_h,
                          self.implicit_eta, values)
        self._remember_decrements(fields, L, dt, values)
        return values

    def _known_decrements(self, fields, L, dt: float) -> np.ndarray | None:
        """The decrements last solved (`_remember_decrements`) if they were solved at this
        state, L and dt, else None. A Newton iteration solves the return at one L in its
        line search's energy, its gradient and its tangent: once, with this. The key
        compares the arrays (O(n d^2) reads, small beside one return per particle)."""
        key = self._decrement_key
        if self.mode != HB_IMPLICIT or key is None:
            return None
        b, J = fields["b"], fields["J"]
        if key[0] == dt and key[1].shape == L.shape and np.array_equal(key[1], L) and \
                np.array_equal(key[2], b) and np.array_equal(key[3], J):
            return self._decrement_values
        return None

    def _decrement_slots(self, fields, L, dt: float) -> tuple[np.ndarray, bool]:
        """(decrements, known) for the energy and gradient kernels: the ones remembered at
        this point, or an array for the kernel to solve them into (empty outside
        HB_IMPLICIT)."""
        known = self._known_decrements(fields, L, dt)
        if known is not None:
            return known, True
        return (np.empty(len(L)) if self.mode == HB_IMPLICIT else _NO_DECREMENTS), False

    def _remember_decrements(self, fields, L, dt: float, values: np.ndarray) -> None:
        self._decrement_key = (dt, L.copy(), fields["b"].copy(), fields["J"].copy())
        self._decrement_values = values

"""Implicit (backward Euler) isochoric viscoplastic return on b_E as a variational update, for
Herschel-Bulkley and von Mises under the semi-implicit integrator (Ortiz & Stainier 1999;
exponential-map return in principal logarithmic strains, Simo 1992; 000 §4.2.5, §4.6.2).

Why. The issue's b_hat(L) = S + dt (L R + R^T L^T) + dt^2 L B L^T evaluates the flow at t^n
and scales the pushed-forward b^n by c = 1/(1 + alpha): the potential's gradient, the force the
solve balances, is ~c times the stress of the updated state, and alpha = O(1) wherever the
relaxation time |dev b|/gdot of the flow is below dt (the walls of the Bingham channel at its
advective dt). Here the return acts on the trial state after the push-forward, at the end of
the step, and is the minimiser of an incremental potential whose plastic variable does not
depend on L, so (envelope theorem) the potential's gradient is exactly the stress of the
returned state and its Hessian is the consistent tangent.

Plane strain (d = 2). With A = I + dt L, J = J^n det A, the trial b_tr = A b^n A^T and its
isochoric part b_bar = b_tr / sqrt(det b_tr) = cosh(delta_tr) I + X, X = dev b_bar,
sinh(delta_tr) = s_tr = |X| / sqrt 2 (delta_tr = e_1 - e_2, the difference of the principal
elastic log stretches). The return keeps the principal directions and J and removes
Delta >= 0 from delta (an isochoric plastic log strain, D_p = Delta / (sqrt 2 dt) N):

    delta = delta_tr - Delta,   b_E = J [cosh(delta) I + (sinh(delta) / s_tr) X]
    |dev b_E| = sqrt 2 J sinh(delta),  tr b_E = 2 J cosh(delta),  det b_E = J^2

Incremental potential per unit V0 (psi of 000 eq. 5.8, D the HB dissipation of the step):

    e(L) = min_{Delta >= 0} mu (J cosh(delta_tr - Delta) - 1) - mu ln J + lam/2 (J - 1)^2
                            + D(Delta)
    D(Delta) = mu/sqrt2 [sigma_Y Delta + eta sqrt2 dt x^(h+1) / (h + 1)],  x = Delta/(sqrt2 dt)

Stationarity in Delta is the HB law at the end of the step: |dev b_E^{n+1}| = sigma_Y +
eta gdot^h with gdot = x = |D_p|, i.e. gdot = ((|dev b_E^{n+1}| - sigma_Y)/eta)^(1/h), the
flow rule of 000 §4.2.5 (on the rescaled b, det b = J^2, as the explicit HB update) with the
rate of the issue's law, L_v b = -(2/d) tr b gdot dev b/|dev b|, to O(|dev b|^2) (its log-strain
form has an extra factor cosh^2(delta) = 1 + O(|dev b|^2)). No flow when sqrt2 J s_tr <=
sigma_Y. eta = 0 is von Mises: sinh(delta) = sigma_Y / (sqrt2 J) exactly.

Derivatives. Delta is stationary, so de/dL = dt tau^{n+1} A^-T with
tau^{n+1} = mu (b_E - I) + lam (J - 1) J I (000 eq. 5.9): the force is the stress of the state
`update_state` stores. The Hessian is the derivative of dt tau A^-T, with dDelta from the
implicit function theorem on g(Delta) = mu J sinh(delta) - D'(Delta) = 0:
k dDelta = mu J cosh(delta) d(delta_tr) + mu sinh(delta) dJ, k = mu J cosh(delta) + D''(Delta).
It is symmetric because e is a potential. Three dimensions would need the two-parameter return
in the deviatoric plane of principal log strains (an eigendecomposition); not built: 3D scenes
use the explicit update (`herschel_bulkley.py`).
"""

from __future__ import annotations

import math

from numba import njit

from .matrix import (add, add_identity, axpy, ddot, det, inverse, mul, mul_bt, scale, sym, trace,
                     transpose)

SQRT2 = math.sqrt(2.0)
# Newton on the scalar return: relative bracket width at which it stops (round-off level).
RETURN_TOLERANCE = 1e-15
RETURN_ITERATIONS = 200


@njit(cache=True)
def dissipation_slope(Delta, dt, sigma_y, h, eta):
    """D'(Delta) / mu = (sigma_Y + eta x^h) / sqrt2, x = Delta / (sqrt2 dt)."""
    x = Delta / (SQRT2 * dt)
    return (sigma_y + (eta * x ** h if eta > 0.0 else 0.0)) / SQRT2


@njit(cache=True)
def dissipation(Delta, dt, sigma_y, h, eta):
    """D(Delta) / mu."""
    x = Delta / (SQRT2 * dt)
    viscous = eta * SQRT2 * dt * x ** (h + 1.0) / (h + 1.0) if eta > 0.0 else 0.0
    return (sigma_y * Delta + viscous) / SQRT2


@njit(cache=True)
def plastic_decrement(J, delta_tr, dt, sigma_y, h, eta):
    """Delta of the return (module docstring), 0 without flow: the root of
    g(Delta) = J sinh(delta_tr - Delta) - D'(Delta)/mu, decreasing in Delta. Newton,
    safeguarded by bisection on a bracket [0, hi]: the root lies below the rate-independent
    return (D' >= sigma_Y/sqrt2) and below the decrement the trial stress's own rate would
    give (the stress falls as Delta grows). For h > 1 Newton runs on the inverted law,
    phi(Delta) = Delta - sqrt2 dt ((sqrt2 J sinh(delta_tr - Delta) - sigma_Y)/eta)^(1/h),
    whose power 1/h is mild where D' ~ x^h is steep (h = 10: 49 iterations on g, most of
    them bisections, against 13 on phi; hb_mixer_2d). D'' is unbounded at 0 for h < 1."""
    if SQRT2 * J * math.sinh(delta_tr) <= sigma_y:
        return 0.0
    if eta == 0.0:  # von Mises: |dev b_E| = sigma_Y
        return delta_tr - math.asinh(sigma_y / (SQRT2 * J))
    inverse = 1.0 / h
    rate_bound = SQRT2 * dt * ((SQRT2 * J * math.sinh(delta_tr) - sigma_y) / eta) ** inverse
    lo, hi = 0.0, min(delta_tr - math.asinh(sigma_y / (SQRT2 * J)), rate_bound)
    Delta = 0.5 * hi
    for _ in range(RETURN_ITERATIONS):
        sh = math.sinh(delta_tr - Delta)
        g = J * sh - dissipation_slope(Delta, dt, sigma_y, h, eta)
        if g > 0.0:
            lo = Delta
        else:
            hi = Delta
        if hi - lo <= RETURN_TOLERANCE * delta_tr:
            break
        ch = J * math.cosh(delta_tr - Delta)
        if h > 1.0:
            q = (SQRT2 * J * sh - sigma_y) / eta
            if q > 0.0:
                qh = q ** inverse
                dphi = 1.0 + 2.0 * dt * qh * ch / (h * q * eta)
                step = Delta - (Delta - SQRT2 * dt * qh) / dphi
            else:  # beyond the rate-independent return: only bisection knows where to go
                step = hi
        else:
            x = Delta / (SQRT2 * dt)
            slope = ch + (eta * h * x ** (h - 1.0) / (2.0 * dt) if x > 0.0 else 0.0)
            step = Delta + g / slope
        if not (lo < step < hi):
            step = 0.5 * (lo + hi)
        elif abs(step - Delta) <= RETURN_TOLERANCE * delta_tr:
            Delta = step
            break
        if step == Delta:
            break
        Delta = step
    return Delta


@njit(cache=True)
def trial(bn, L, dt, Jn):
    """A^-T, J, b_bar = b_tr/sqrt(det b_tr), X = dev b_bar, s_tr = |X|/sqrt2, P = A b^n,
    sqrt(det b_tr) of the trial state b_tr = A b^n A^T (2D)."""
    A = add_identity(scale(dt, L), 1.0)
    J = Jn * det(A)
    P = mul(A, bn)
    btr = sym(mul_bt(P, A))
    root = math.sqrt(det(btr))
    bbar = scale(1.0 / root, btr)
    X = add_identity(bbar, -0.5 * trace(bbar))
    s_tr = math.sqrt(0.5 * ddot(X, X))
    return transpose(inverse(A)), J, bbar, X, s_tr, P, root


@njit(cache=True)
def returned(bn, L, dt, Jn, Delta):
    """(b_E^{n+1}, J, Delta, delta, A^-T) of the return with its decrement Delta at L
    (`decrement`): b_E (2D), the decrement, the returned delta (module docstring)."""
    AiT, J, bbar, X, s_tr, P, root = trial(bn, L, dt, Jn)
    delta_tr = math.asinh(s_tr)
    if Delta == 0.0:
        return scale(J, bbar), J, 0.0, delta_tr, AiT
    delta = delta_tr - Delta
    bE = scale(J, axpy(math.sinh(delta) / s_tr, X, add_identity(scale(0.0, X), math.cosh(delta))))
    return bE, J, Delta, delta, AiT


@njit(cache=True)
def energy_and_decrement(bn, L, dt, Jn, mu, lam, sigma_y, h, eta):
    """(e(L)/V0, Delta at L): `energy_density` and the decrement it solved for, so the
    gradient and tangent at the same L need not solve the return again (Delta 0 where e is
    +inf)."""
    AiT, J, bbar, X, s_tr, P, root = trial(bn, L, dt, Jn)
    if not (J > 0.0 and root > 0.0):  # NaN-safe
        return math.inf, 0.0
    delta_tr = math.asinh(s_tr)
    Delta = plastic_decrement(J, delta_tr, dt, sigma_y, h, eta)
    return _returned_energy(J, delta_tr, Delta, dt, mu, lam, sigma_y, h, eta), Delta


@njit(cache=True)
def energy_density(bn, L, dt, Jn, mu, lam, sigma_y, h, eta, Delta):
    """e(L)/V0 (module docstring) with the return's decrement Delta at L (`decrement`), +inf
    when J <= 0 or b_tr is not SPD."""
    AiT, J, bbar, X, s_tr, P, root = trial(bn, L, dt, Jn)
    if not (J > 0.0 and root > 0.0):  # NaN-safe
        return math.inf
    return _returned_energy(J, math.asinh(s_tr), Delta, dt, mu, lam, sigma_y, h, eta)


@njit(cache=True, inline="always")
def _returned_energy(J, delta_tr, Delta, dt, mu, lam, sigma_y, h, eta):
    """e/V0 of the returned state from the trial's J and delta_tr and the decrement."""
    return (mu * (J * math.cosh(delta_tr - Delta) - 1.0) - mu * math.log(J)
            + 0.5 * lam * (J - 1.0) * (J - 1.0)
            + mu * dissipation(Delta, dt, sigma_y, h, eta))


@njit(cache=True)
def kirchhoff_returned(bE, J, mu, lam):
    """tau = mu (b_E - I) + lam (J - 1) J I (000 eq. 5.9) of a b_E with det J^2."""
    return add_identity(scale(mu, bE), lam * (J - 1.0) * J - mu)


@njit(cache=True)
def gradient_point(bn, L, dt, Jn, mu, lam, Delta):
    """(de/dL)/(dt V0) = tau^{n+1} A^-T with the return's decrement Delta at L (`decrement`),
    and admissibility (J > 0, det b_tr > 0)."""
    bE, J, Delta, delta, AiT = returned(bn, L, dt, Jn, Delta)
    ok = J > 0.0 and det(bE) > 0.0
    return mul(kirchhoff_returned(bE, J, mu, lam), AiT), ok


@njit(cache=True)
def decrement(bn, L, dt, Jn, sigma_y, h, eta):
    """Delta of the return at L (0 without flow or when J <= 0)."""
    AiT, J, bbar, X, s_tr, P, root = trial(bn, L, dt, Jn)
    if not J > 0.0:
        return 0.0
    return plastic_decrement(J, math.asinh(s_tr), dt, sigma_y, h, eta)


@njit(cache=True)
def hessian_point(bn, L, D, dt, Jn, mu, lam, sigma_y, h, eta, Delta):
    """D^2 e[D]/(dt V0): the derivative of tau A^-T in the direction D (module docstring);
    Delta is the return's decrement at L (`decrement`), solved once per linearisation point
    rather than per Hessian product."""
    AiT, J, bbar, X, s_tr, P, root = trial(bn, L, dt, Jn)
    j1 = ddot(AiT, D)                                   # tr(A^-1 D)
    dJ = J * dt * j1
    DPt = mul_bt(D, P)                                  # D b^n A^T
    dbbar = axpy(-dt * j1, bbar, scale(dt / root, add(DPt, transpose(DPt))))
    delta_tr = math.asinh(s_tr)
    if Delta == 0.0:
        bE = scale(J, bbar)
        dbE = axpy(dJ, bbar, scale(J, dbbar))
    else:
        delta = delta_tr - Delta
        sh, ch = math.sinh(delta), math.cosh(delta)
        dX = add_identity(dbbar, -0.5 * trace(dbbar))
        ds = 0.5 * ddot(X, dX) / s_tr
        ddelta_tr = ds / math.sqrt(1.0 + s_tr * s_tr)
        x = Delta / (SQRT2 * dt)
        k = J * ch + (eta * h * x ** (h - 1.0) / (2.0 * dt) if eta > 0.0 else 0.0)
        ddelta = ddelta_tr - (J * ch * ddelta_tr + sh * dJ) / k
        r = sh / s_tr
        dr = ch * ddelta / s_tr - sh * ds / (s_tr * s_tr)
        bbar_new = axpy(r, X, add_identity(scale(0.0, X), ch))
        dbbar_new = add_identity(axpy(dr, X, scale(r, dX)), sh * ddelta)
        bE = scale(J, bbar_new)
        dbE = axpy(dJ, bbar_new, scale(J, dbbar_new))
    tau = kirchhoff_returned(bE, J, mu, lam)
    dtau = add_identity(scale(mu, dbE), lam * (2.0 * J - 1.0) * dJ)
    dAiT = scale(-dt, mul(mul_bt(AiT, D), AiT))         # -dt A^-T D^T A^-T
    return add(mul(dtau, AiT), mul(tau, dAiT))


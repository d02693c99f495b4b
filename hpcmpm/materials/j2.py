"""J2 (von Mises) plasticity with Johnson-Cook hardening, hypoelastic and objective (003 §7.3,
appendix B, with the issue's corrections).

003 takes the trial stress from a hyperelastic model, which has no elastic state to return
to. Here the deviatoric Cauchy stress s is the state, advanced by the Hughes-Winget
objective update (Hughes and Winget 1980):

    s* = R s R^T + 2 mu dt dev D,   R = (I - dt W/2)^-1 (I + dt W/2),   D = sym L, W = skew L

(R is the Cayley transform of dt W/2: an exact rotation, so a rigid spin keeps |s| to
round-off), then the radial return of appendix B onto the Johnson-Cook yield stress (003
eq. 7.7, Johnson and Cook 1983)

    sigma_y(eps_p, eps_dot_p, T) = (A + B eps_p^n) (1 + C ln max(eps_dot_p/eps_dot0, 1)) (1 - T*^m),

T* = (T - T_room)/(T_melt - T_room) clipped to [0, 1] (the factor is 1 when isothermal). The
max(., 1) keeps the rate factor >= 1 (003 prints ln(eps_dot_p/eps_dot0), negative and
unbounded below as the rate falls).

Return map. With s_eq = sqrt(3/2 s*:s*) above sigma_y(eps_p, 0), the plastic increment
d solves g(d) = s_eq - 3 mu d - sigma_y(eps_p + d, d/dt) = 0 (B.4 without the linearization;
`return_map = "newton"`, the default) by Newton's method kept inside the bracket
[0, (s_eq - sigma_y(eps_p, 0))/(3 mu)] (bisection when a step leaves it), to
|g| <= 1e-10 sigma_y (RETURN_TOL). Then s = (1 - 3 mu d/s_eq) s*.
`return_map = "linearized"` is B.5-B.8 as printed: d = f/(3 mu + E^p),
sigma_y <- sigma_y + E^p d, s = sigma_y/s_eq s*, with E^p = dsigma_y/deps_p of eq. 7.8 at the
start-of-step eps_p and eps_dot_p taken as the equivalent total deviatoric strain rate
sqrt(2/3 dev D:dev D) (the plastic rate is not known before the return). E^p is infinite at
eps_p = 0 for n < 1 (then B.5 never leaves eps_p = 0); there the first plastic step takes
E^p = 0 (perfectly plastic).

Heating (Johnson and Cook 1983; 003 is isothermal): with ``specific_heat`` c_v,
dT = 0.9 sigma_y d/(rho c_v) after the return, the softening factor of a step taken at the
start-of-step T (explicit in T).

Pressure: sigma = s - (p + q) I with p from the ``eos`` (Mie-Grüneisen of J, E) or, without
one, p = -K ln J (K = lam + 2 mu/3); q the artificial viscosity; E by the energy balance of
`eos`. J <- det(I + dt L) J, as the engine advances F (so a rigid spin, whose forward-Euler
map spreads the particles by 1 + dt^2 |W|^2, changes J with them while |s| is kept).

2D is plane strain: the out-of-plane deviator s_zz is a field of its own (dev D has the
component -tr D/3 along z), the yield criterion and the energy use all of s.

Fields: s (deviatoric Cauchy stress, in-plane in 2D), s_zz (2D only), J, E, eps_p, pressure,
T (only with specific_heat).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..errors import SceneError
from ..state import SCALAR, TENSOR, FieldSpec
from .eos import (EOS_SCHEMA, VISCOSITY_PARAMS, Volumetric, record_failure, total_pressure,
                  volume_step)
from .failure import SPB_FAILURE, SPB_FIELDS
from .impact import ImpactMaterial, kirchhoff2, kirchhoff3
from .params import POISSON, YOUNG, Param, choice, lame, table
from .tensors import det3, load2, load3, store2, store3

NEWTON, LINEARIZED = 0, 1
# Newton stops at |g| <= RETURN_TOL sigma_y: half the promised 1e-10, so the round-off of
# scaling s and forming sqrt(3/2 s:s) afterwards cannot cross the promise.
RETURN_TOL = 5.0e-11
MAX_ITERATIONS = 200
TAYLOR_QUINNEY = 0.9  # fraction of plastic work that heats (Johnson and Cook 1983)

JOHNSON_COOK_SCHEMA = {
    "type": choice(("johnson_cook",), doc="hardening law"),
    "A": Param(0.0, math.inf, doc="yield stress at eps_p = 0 (stress units)"),
    "B": Param(0.0, math.inf, required=False, default=0.0, low_inclusive=True,
               doc="strain-hardening coefficient (stress units)"),
    "n": Param(0.0, math.inf, required=False, default=1.0, low_inclusive=True,
               doc="strain-hardening exponent (0: perfectly plastic at A + B)"),
    "C": Param(0.0, math.inf, required=False, default=0.0, low_inclusive=True,
               doc="strain-rate coefficient"),
    "eps_dot0": Param(0.0, math.inf, required=False, default=1.0,
                      doc="reference plastic strain rate (1/time; 003: 1/s)"),
    "m": Param(0.0, math.inf, required=False, default=1.0, doc="thermal-softening exponent"),
    "T_melt": Param(0.0, math.inf, required=False,
                    doc="melting temperature (needed with specific_heat)"),
    "T_room": Param(0.0, math.inf, required=False, default=293.0,
                    doc="reference (and initial) temperature"),
}


# -- Johnson-Cook flow stress ----------------------------------------------------------------
@njit(cache=True, inline="always")
def jc_hardening(eps, B, n):
    """(B eps^n, d/deps): inf slope at eps = 0 for 0 < n < 1."""
    if n == 0.0:
        return B, 0.0
    if eps <= 0.0:
        return 0.0, (B if n == 1.0 else (math.inf if n < 1.0 else 0.0))
    h = B * eps ** n
    return h, n * h / eps


@njit(cache=True, inline="always")
def jc_rate_factor(rate, C, eps_dot0):
    """(1 + C ln max(rate/eps_dot0, 1), d/drate)."""
    r = rate / eps_dot0
    if r <= 1.0:
        return 1.0, 0.0
    return 1.0 + C * math.log(r), C / rate


@njit(cache=True, inline="always")
def jc_yield(eps, rate, A, B, n, C, eps_dot0, theta):
    """sigma_y(eps_p, eps_dot_p) with the thermal factor theta = 1 - T*^m (003 eq. 7.7)."""
    h, _ = jc_hardening(eps, B, n)
    f, _ = jc_rate_factor(rate, C, eps_dot0)
    return (A + h) * f * theta


@njit(cache=True, inline="always")
def thermal_factor(T, T_room, T_melt, m):
    """1 - T*^m, T* = (T - T_room)/(T_melt - T_room) clipped to [0, 1]."""
    t = (T - T_room) / (T_melt - T_room)
    if t <= 0.0:
        return 1.0
    if t >= 1.0:
        return 0.0
    return 1.0 - t ** m


@njit(cache=True)
def return_newton(s_eq, eps, dt, mu3, A, B, n, C, eps_dot0, theta):
    """(d, sigma_y) with g(d) = s_eq - 3 mu d - sigma_y(eps + d, d/dt) = 0 (module docstring);
    d = 0 when s_eq <= sigma_y(eps, 0) (elastic)."""
    sy0 = jc_yield(eps, 0.0, A, B, n, C, eps_dot0, theta)
    if s_eq <= sy0:
        return 0.0, sy0
    lo = 0.0
    hi = (s_eq - sy0) / mu3  # g(hi) = sy0 - sigma_y(eps + hi, .) <= 0
    x = hi
    sy = sy0
    for _ in range(MAX_ITERATIONS):
        h, dh = jc_hardening(eps + x, B, n)
        rate = x / dt if dt > 0.0 else 0.0
        f, df = jc_rate_factor(rate, C, eps_dot0)
        sy = (A + h) * f * theta
        g = s_eq - mu3 * x - sy
        if abs(g) <= RETURN_TOL * sy + 4.0e-16 * s_eq:
            return x, sy
        if g > 0.0:
            lo = x
        else:
            hi = x
        dg = -mu3 - theta * (dh * f + (A + h) * df / dt if dt > 0.0 else dh * f)
        xn = x - g / dg
        if not (lo < xn < hi):  # also catches an infinite slope (xn = x) and NaN
            xn = 0.5 * (lo + hi)
        if hi - lo <= 1e-16 * hi:
            return x, sy
        x = xn
    return x, sy


@njit(cache=True)
def return_linearized(s_eq, eps, rate, mu3, A, B, n, C, eps_dot0, theta):
    """(d, sigma_y^{n+1}) of appendix B.5-B.7 (module docstring); d = 0 when elastic."""
    h, dh = jc_hardening(eps, B, n)
    f, _ = jc_rate_factor(rate, C, eps_dot0)
    sy = (A + h) * f * theta
    if s_eq <= sy:
        return 0.0, sy
    Ep = dh * f * theta  # 003 eq. 7.8
    if not math.isfinite(Ep):
        Ep = 0.0  # eps_p = 0, n < 1: the printed E^p is infinite
    d = (s_eq - sy) / (mu3 + Ep)  # B.5
    return d, sy + Ep * d  # B.6-B.7


@njit(cache=True, inline="always")
def _plastic_step(s_eq, eps, dt, rate_total, mu3, A, B, n, C, eps_dot0, theta, method):
    if method == NEWTON:
        return return_newton(s_eq, eps, dt, mu3, A, B, n, C, eps_dot0, theta)
    return return_linearized(s_eq, eps, rate_total, mu3, A, B, n, C, eps_dot0, theta)


# -- state update ----------------------------------------------------------------------------
@njit(cache=True)
def _update_state_2d(L, S, Szz, J, E, P, EPS, T, dt, mu, hardening, thermal, method, rho0,
                     specific_heat, kind, c0, s_, gamma0, K, length, q1, q2, bad_index, bad_J):
    """Plane-strain update of S (n, 2, 2), Szz, J, E, P, EPS, T (n,) from L (n, 2, 2)."""
    A, B, n, C, eps_dot0, m, T_melt, T_room = hardening
    mu3 = 3.0 * mu
    shear = 4.0 / 3.0 * mu
    nbad = 0
    for p in range(L.shape[0]):
        l = load2(L, p)
        d00, d11 = l[0], l[3]
        d01 = 0.5 * (l[1] + l[2])
        a = 0.25 * dt * (l[1] - l[2])  # Omega = dt W/2 = [[0, a], [-a, 0]]
        inv = 1.0 / (1.0 + a * a)
        c, sn = (1.0 - a * a) * inv, 2.0 * a * inv  # R = [[c, sn], [-sn, c]]
        s = load2(S, p)
        # R s R^T, symmetric by construction (s01 = s10 stored)
        r00 = c * c * s[0] + 2.0 * c * sn * s[1] + sn * sn * s[3]
        r11 = sn * sn * s[0] - 2.0 * c * sn * s[1] + c * c * s[3]
        r01 = (c * c - sn * sn) * s[1] + c * sn * (s[3] - s[0])
        rzz = Szz[p]
        tr_d = d00 + d11
        # dev D of the plane-strain D (D_zz = 0), differences so a dilatation gives exact 0
        e00, e11, ezz = (2.0 * d00 - d11) / 3.0, (2.0 * d11 - d00) / 3.0, -tr_d / 3.0
        t00 = r00 + 2.0 * mu * dt * e00
        t11 = r11 + 2.0 * mu * dt * e11
        t01 = r01 + 2.0 * mu * dt * d01
        tzz = rzz + 2.0 * mu * dt * ezz
        s_eq = math.sqrt(1.5 * (t00 * t00 + t11 * t11 + tzz * tzz + 2.0 * t01 * t01))
        theta = thermal_factor(T[p], T_room, T_melt, m) if thermal else 1.0
        rate = math.sqrt(2.0 / 3.0 * (e00 * e00 + e11 * e11 + ezz * ezz + 2.0 * d01 * d01))
        dep, sy = _plastic_step(s_eq, EPS[p], dt, rate, mu3, A, B, n, C, eps_dot0, theta,
                                method)
        if dep > 0.0:
            k = sy / s_eq if method == LINEARIZED else 1.0 - mu3 * dep / s_eq
            t00 *= k
            t11 *= k
            t01 *= k
            tzz *= k
        # s:D at the midpoint of the step (s_zz D_zz = 0 in plane strain)
        work = 0.5 * ((r00 + t00) * d00 + (r11 + t11) * d11 + 2.0 * (r01 + t01) * d01)
        ratio = (1.0 + dt * l[0]) * (1.0 + dt * l[3]) - dt * dt * l[1] * l[2]
        J1, E1, p1 = volume_step(J[p], E[p], ratio, tr_d, dt, work, shear, kind, rho0, c0, s_,
                                 gamma0, K, length, q1, q2)
        if not math.isfinite(p1):
            nbad = record_failure(p, J1, nbad, bad_index, bad_J)
            J[p] = math.nan
            continue
        store2(S, p, (t00, t01, t01, t11))
        Szz[p] = tzz
        EPS[p] += dep
        if thermal and dep > 0.0:
            T[p] += TAYLOR_QUINNEY * sy * dep * J1 / (rho0 * specific_heat)
        J[p] = J1
        E[p] = E1
        P[p] = p1
    return nbad


@njit(cache=True, inline="always")
def _rotate3(R, s):
    """R s R^T for symmetric s (upper triangle mirrored so the result is exactly symmetric)."""
    # M = R s
    m = (R[0] * s[0] + R[1] * s[3] + R[2] * s[6], R[0] * s[1] + R[1] * s[4] + R[2] * s[7],
         R[0] * s[2] + R[1] * s[5] + R[2] * s[8],
         R[3] * s[0] + R[4] * s[3] + R[5] * s[6], R[3] * s[1] + R[4] * s[4] + R[5] * s[7],
         R[3] * s[2] + R[4] * s[5] + R[5] * s[8],
         R[6] * s[0] + R[7] * s[3] + R[8] * s[6], R[6] * s[1] + R[7] * s[4] + R[8] * s[7],
         R[6] * s[2] + R[7] * s[5] + R[8] * s[8])
    a00 = m[0] * R[0] + m[1] * R[1] + m[2] * R[2]
    a01 = m[0] * R[3] + m[1] * R[4] + m[2] * R[5]
    a02 = m[0] * R[6] + m[1] * R[7] + m[2] * R[8]
    a11 = m[3] * R[3] + m[4] * R[4] + m[5] * R[5]
    a12 = m[3] * R[6] + m[4] * R[7] + m[5] * R[8]
    a22 = m[6] * R[6] + m[7] * R[7] + m[8] * R[8]
    return (a00, a01, a02, a01, a11, a12, a02, a12, a22)


@njit(cache=True, inline="always")
def cayley3(w01, w02, w12):
    """R = (I - Om)^-1 (I + Om) = I + 2 (Om + Om^2)/(1 + |w|^2) for the skew
    Om = [[0, w01, w02], [-w01, 0, w12], [-w02, -w12, 0]]."""
    k = 2.0 / (1.0 + w01 * w01 + w02 * w02 + w12 * w12)
    # Om^2 (symmetric)
    o00 = -w01 * w01 - w02 * w02
    o11 = -w01 * w01 - w12 * w12
    o22 = -w02 * w02 - w12 * w12
    o01 = -w02 * w12
    o02 = w01 * w12
    o12 = -w01 * w02
    return (1.0 + k * o00, k * (w01 + o01), k * (w02 + o02),
            k * (-w01 + o01), 1.0 + k * o11, k * (w12 + o12),
            k * (-w02 + o02), k * (-w12 + o12), 1.0 + k * o22)


@njit(cache=True)
def _update_state_3d(L, S, Szz, J, E, P, EPS, T, dt, mu, hardening, thermal, method, rho0,
                     specific_heat, kind, c0, s_, gamma0, K, length, q1, q2, bad_index, bad_J):
    """3D update of S (n, 3, 3), J, E, P, EPS, T (n,) from L (n, 3, 3); Szz unused."""
    A, B, n, C, eps_dot0, m, T_melt, T_room = hardening
    mu3 = 3.0 * mu
    shear = 4.0 / 3.0 * mu
    nbad = 0
    for p in range(L.shape[0]):
        l = load3(L, p)
        h = 0.25 * dt
        R = cayley3(h * (l[1] - l[3]), h * (l[2] - l[6]), h * (l[5] - l[7]))
        r = _rotate3(R, load3(S, p))
        tr_d = l[0] + l[4] + l[8]
        # dev D, diagonal as differences so a dilatation gives exact 0
        e = ((2.0 * l[0] - l[4] - l[8]) / 3.0, 0.5 * (l[1] + l[3]), 0.5 * (l[2] + l[6]),
             0.5 * (l[1] + l[3]), (2.0 * l[4] - l[0] - l[8]) / 3.0, 0.5 * (l[5] + l[7]),
             0.5 * (l[2] + l[6]), 0.5 * (l[5] + l[7]), (2.0 * l[8] - l[0] - l[4]) / 3.0)
        k2 = 2.0 * mu * dt
        t = (r[0] + k2 * e[0], r[1] + k2 * e[1], r[2] + k2 * e[2],
             r[3] + k2 * e[3], r[4] + k2 * e[4], r[5] + k2 * e[5],
             r[6] + k2 * e[6], r[7] + k2 * e[7], r[8] + k2 * e[8])
        tt = 0.0
        ee = 0.0
        for k in range(9):
            tt += t[k] * t[k]
            ee += e[k] * e[k]
        s_eq = math.sqrt(1.5 * tt)
        theta = thermal_factor(T[p], T_room, T_melt, m) if thermal else 1.0
        rate = math.sqrt(2.0 / 3.0 * ee)
        dep, sy = _plastic_step(s_eq, EPS[p], dt, rate, mu3, A, B, n, C, eps_dot0, theta,
                                method)
        if dep > 0.0:
            k = sy / s_eq if method == LINEARIZED else 1.0 - mu3 * dep / s_eq
            t = (k * t[0], k * t[1], k * t[2], k * t[3], k * t[4], k * t[5],
                 k * t[6], k * t[7], k * t[8])
        work = 0.0
        for k in range(9):
            work += (r[k] + t[k]) * e[k]  # s:D = s:dev D for deviatoric s
        ratio = det3((1.0 + dt * l[0], dt * l[1], dt * l[2],
                      dt * l[3], 1.0 + dt * l[4], dt * l[5],
                      dt * l[6], dt * l[7], 1.0 + dt * l[8]))
        J1, E1, p1 = volume_step(J[p], E[p], ratio, tr_d, dt, 0.5 * work, shear, kind, rho0, c0,
                                 s_, gamma0, K, length, q1, q2)
        if not math.isfinite(p1):
            nbad = record_failure(p, J1, nbad, bad_index, bad_J)
            J[p] = math.nan
            continue
        store3(S, p, t)
        EPS[p] += dep
        if thermal and dep > 0.0:
            T[p] += TAYLOR_QUINNEY * sy * dep * J1 / (rho0 * specific_heat)
        J[p] = J1
        E[p] = E1
        P[p] = p1
    return nbad


# -- stress ----------------------------------------------------------------------------------
@njit(cache=True)
def _stress_2d(L, S, J, E, tau, shear, kind, rho0, c0, s_, gamma0, K, length, q1, q2):
    """tau = J (s - (p + q) I), in plane, (n, 2, 2)."""
    for p in range(J.shape[0]):
        Jp = J[p]
        pq = total_pressure(Jp, E[p], L[p, 0, 0] + L[p, 1, 1], shear, kind, rho0, c0, s_,
                            gamma0, K, length, q1, q2)
        store2(tau, p, kirchhoff2(Jp, load2(S, p), pq))


@njit(cache=True)
def _stress_3d(L, S, J, E, tau, shear, kind, rho0, c0, s_, gamma0, K, length, q1, q2):
    """tau = J (s - (p + q) I), (n, 3, 3)."""
    for p in range(J.shape[0]):
        Jp = J[p]
        pq = total_pressure(Jp, E[p], L[p, 0, 0] + L[p, 1, 1] + L[p, 2, 2], shear, kind, rho0,
                            c0, s_, gamma0, K, length, q1, q2)
        store3(tau, p, kirchhoff3(Jp, load3(S, p), pq))


class J2Plasticity(ImpactMaterial):
    """Hypoelastic J2 plasticity with Johnson-Cook hardening (module docstring)."""

    name = "j2"
    parameters = {
        "E": YOUNG,
        "nu": POISSON,
        "hardening": table(JOHNSON_COOK_SCHEMA, required=True, doc="yield stress law table"),
        "return_map": choice(("newton", "linearized"), "newton",
                             doc="exact return (bracketed Newton) or 003 B.5's linearized step"),
        "specific_heat": Param(0.0, math.inf, required=False,
                               doc="c_v (energy/(mass temperature)): adiabatic heating and "
                                   "thermal softening; isothermal if absent"),
        "eos": table(EOS_SCHEMA, doc="equation of state table; p = -K ln J if absent"),
        **VISCOSITY_PARAMS,
        "failure": SPB_FAILURE,
    }
    # Every field a j2 material may carry (what the scene validator reads from the class);
    # an instance declares its own subset: s_zz in 2D only, T only with specific_heat.
    fields = {"s": FieldSpec(TENSOR, "f8", 0.0), "J": FieldSpec(SCALAR, "f8", 1.0),
              "E": FieldSpec(SCALAR, "f8", 0.0), "eps_p": FieldSpec(SCALAR, "f8", 0.0),
              "pressure": FieldSpec(SCALAR, "f8", 0.0), "s_zz": FieldSpec(SCALAR, "f8", 0.0),
              "T": FieldSpec(SCALAR, "f8", 293.0)}

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        q = self.params
        self.mu, self.lam = lame(q["E"], q["nu"])
        self.shear_term = 4.0 / 3.0 * self.mu  # plane strain and 3D
        self.volumetric_response = Volumetric(q["eos"], self.density,
                                              self.lam + 2.0 * self.mu / 3.0, q["q1"], q["q2"])
        h = q["hardening"]
        self.thermal = q["specific_heat"] is not None
        if self.thermal:
            where = f"material {spec.name!r} ({self.name})"
            if h["T_melt"] is None:
                raise SceneError(f"{where}: hardening.T_melt: missing (required with "
                                 f"specific_heat)")
            if not h["T_melt"] > h["T_room"]:
                raise SceneError(f"{where}: hardening.T_melt: must be > T_room = "
                                 f"{h['T_room']:g}, got {h['T_melt']:g}")
        self.hardening = (h["A"], h["B"], h["n"], h["C"], h["eps_dot0"], h["m"],
                          h["T_melt"] if self.thermal else math.inf, h["T_room"])
        self.method = NEWTON if q["return_map"] == "newton" else LINEARIZED
        self.specific_heat = q["specific_heat"] if self.thermal else 1.0
        fields = {k: v for k, v in type(self).fields.items() if k not in ("s_zz", "T")}
        if dim == 2:
            fields["s_zz"] = type(self).fields["s_zz"]
        if self.thermal:
            fields["T"] = FieldSpec(SCALAR, "f8", float(h["T_room"]))
        if self.failure:             # SPB-MPM (attach_failure declared them on the class's)
            fields.update(SPB_FIELDS)
        self.fields = fields
        self._state = _update_state_2d if dim == 2 else _update_state_3d
        self._stress = _stress_2d if dim == 2 else _stress_3d
        self._none = np.zeros(0)

    def yield_stress(self, eps_p: float, rate: float = 0.0, T: float | None = None) -> float:
        """sigma_y of 003 eq. 7.7 (rate factor floored at 1) at one state."""
        A, B, n, C, eps_dot0, m, T_melt, T_room = self.hardening
        theta = thermal_factor(T, T_room, T_melt, m) if (self.thermal and T is not None) \
            else 1.0
        return float(jc_yield(eps_p, rate, A, B, n, C, eps_dot0, theta))

    def update_state(self, fields, dt: float) -> None:
        """Objective trial stress, return map, J, E, pressure (and T) over dt from fields["L"]."""
        szz = fields["s_zz"] if self.dim == 2 else self._none
        T = fields["T"] if self.thermal else self._none  # read only when thermal
        vol = self.volumetric_response
        kind, rho0, c0, s, gamma0, K = vol.args
        nbad = self._state(fields["L"], fields["s"], szz, fields["J"], fields["E"],
                           fields["pressure"], fields["eps_p"], T, dt, self.mu,
                           self.hardening, self.thermal, self.method, rho0,
                           self.specific_heat, kind, c0, s, gamma0, K,
                           *self.viscosity_args(), self._bad_index, self._bad_J)
        self.report(fields, nbad)

    def update_stress(self, fields, dt: float) -> None:
        """Write fields["tau"] = J (s - (p + q) I) from the state and the stored L."""
        self._stress(fields["L"], fields["s"], fields["J"], fields["E"], fields["tau"],
                     self.shear_term, *self.volumetric_response.args, *self.viscosity_args())

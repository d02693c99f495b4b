"""Equations of state, artificial viscosity and the internal-energy update of the impact models.

Mie-Grüneisen (003 eq. 7.4, with the issue's corrections). With zeta = rho/rho0 - 1 = 1/J - 1
(J = det F, the total volume ratio) and E the internal energy per *reference* volume,

    p = rho0 c0^2 zeta [1 + (1 - Gamma0/2) zeta] / [1 - (S - 1) zeta]^2 + Gamma0 E   (zeta >= 0)
    p = rho0 c0^2 zeta + Gamma0 E                                                    (zeta < 0)

003 prints the denominator as [1 + (S - 1) zeta]^2: that gives 17.0 GPa instead of the
measured 20.9 GPa for copper at u_p = 500 m/s. With the minus sign the compressive branch is
p_H (1 - Gamma0 eta/2) + Gamma0 E, p_H = rho0 c0^2 eta/(1 - S eta)^2 and eta = 1 - rho0/rho the
Hugoniot of U_s = c0 + S u_p, so a state on the Hugoniot (E = p_H eta/2 = rho0 u_p^2/2) has
p = p_H exactly (Uintah's MieGruneisenEOS writes the same expression as
rho0 c0^2 (1/zeta + 1 - Gamma0/2)/(1/zeta - (S - 1))^2). 003 also writes E - E0 with E a
density on the current volume; here E starts at 0 and is per reference volume.

The compressive branch is singular at zeta = 1/(S - 1). A particle whose
1 - (S - 1) zeta falls below MIN_DENOMINATOR gets NaN pressure (the material then writes NaN
into its J and reports it): there the pressure is already 1e4 times its linear value and the
wave speed 100 times, so a run that reaches it has left the EOS's range (the fix is a lower
impact speed, a finer grid or a larger S, not a smaller time step).

Without an EOS (the J2 model's default) the pressure is the Hencky one, p = -K ln J, with
Gamma0 = 0: the same kernels with `kind` = LOG_BULK.

Sound speed (for the time step): c^2 = dp/drho|_E + Gamma0 rho0 p/rho^2 + k mu/rho, the
thermodynamic speed of the EOS (dp/de|_rho = Gamma0 rho0 with e = E/rho0 per mass) plus the
shear contribution of the strength model (k = 4/3 in 3D and plane strain, 1 for the 2D
continuum of the 2D shock model).

Artificial viscosity (absent in 003; von Neumann and Richtmyer 1950, Wilkins 1980):

    q = rho l (Q1^2 l (tr D)^2 - Q2 c tr D)  for tr D < 0,  0 otherwise,  l = dx,

with Q1 = 1.5, Q2 = 0.06. Its time-step bound (Belytschko et al., Nonlinear Finite Elements,
§6.3; the LS-DYNA bulk-viscosity rule) replaces c by the effective speed
Q + sqrt(Q^2 + c^2), Q = Q2 c + Q1^2 l |tr D|.

Energy (the issue's correction of 003 eq. 7.3: E <- E + dt J sigma:D, D = sym L). Discretised
in time as in Wilkins' hydrocodes, with the volume change dJ = J^{n+1} - J^n for dt J tr D:

    E^{n+1} = E^n + w_dev - dJ (p^n + p^{n+1})/2 - q dJ,

w_dev = dt J s:D the deviatoric work. p^{n+1} = p_c(J^{n+1}) + Gamma0 E^{n+1} is linear in
E^{n+1}, so the trapezoid is solved in closed form. The trapezoid is what makes a shock land on
the Hugoniot: the Rankine-Hugoniot energy jump is E - E0 = (p + p0)/2 (J0 - J).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .params import Param, choice

MIE_GRUNEISEN, LOG_BULK = 0, 1
MIN_DENOMINATOR = 1.0e-2
# How many failing particles a kernel describes in full (the message names the first ones).
MAX_REPORTED = 4

EOS_SCHEMA = {
    "type": choice(("mie_gruneisen",), doc="equation of state"),
    # Bounded so that rho0 c0^2 stays a float64 (a c0 of 1e300 overflowed in validation).
    "c0": Param(0.0, 1e150, doc="bulk sound speed c0 (velocity units)"),
    "s": Param(1.0, math.inf, required=False, default=1.1,
               doc="Hugoniot slope S of U_s = c0 + S u_p (> 1; 003 §7.2.3: 1.1)"),
    "gamma0": Param(0.0, math.inf, required=False, default=1.6, low_inclusive=True,
                    doc="Grueneisen parameter Gamma0 (003 §7.2.3: 1.6)"),
}
VISCOSITY_PARAMS = {
    "q1": Param(0.0, math.inf, required=False, default=None, low_inclusive=True,
                doc="quadratic artificial-viscosity coefficient Q1; default 1.5 with an eos, "
                    "else 0 (off)"),
    "q2": Param(0.0, math.inf, required=False, default=None, low_inclusive=True,
                doc="linear artificial-viscosity coefficient Q2; default 0.06 with an eos, "
                    "else 0 (off)"),
}


@njit(cache=True, inline="always")
def mie_gruneisen(J, E, rho0, c0, s, gamma0):
    """(p, dp/dzeta|_E) of 003 eq. 7.4 (corrected, module docstring); NaN when singular."""
    if not J > 0.0:
        return math.nan, math.nan
    zeta = 1.0 / J - 1.0
    k0 = rho0 * c0 * c0
    if zeta < 0.0:
        return k0 * zeta + gamma0 * E, k0
    x = 1.0 - (s - 1.0) * zeta
    if not x >= MIN_DENOMINATOR:
        return math.nan, math.nan
    a = 1.0 - 0.5 * gamma0
    num = zeta * (1.0 + a * zeta)
    inv_x2 = 1.0 / (x * x)
    dnum = 1.0 + 2.0 * a * zeta
    return (k0 * num * inv_x2 + gamma0 * E,
            k0 * inv_x2 * (dnum + 2.0 * (s - 1.0) * num / x))


@njit(cache=True, inline="always")
def pressure(J, E, kind, rho0, c0, s, gamma0, K):
    """(p, dp/dzeta|_E) for either kind: Mie-Grüneisen, or p = -K ln J (Gamma0 ignored)."""
    if kind == LOG_BULK:
        if not J > 0.0:
            return math.nan, math.nan
        return -K * math.log(J), K * J
    return mie_gruneisen(J, E, rho0, c0, s, gamma0)


@njit(cache=True, inline="always")
def sound_speed_sq(J, p, dp_dzeta, kind, rho0, gamma0, shear):
    """c^2 = dp/drho|_E + Gamma0 rho0 p/rho^2 + shear/rho, rho = rho0/J (module docstring);
    ``shear`` is k mu. Clipped at 0 (deep tension can make the EOS part negative)."""
    g = gamma0 if kind == MIE_GRUNEISEN else 0.0
    c2 = (dp_dzeta + g * p * J * J + shear * J) / rho0
    return c2 if c2 > 0.0 else 0.0


@njit(cache=True, inline="always")
def artificial_viscosity(rho, tr_d, c, length, q1, q2):
    """q = rho l (Q1^2 l (tr D)^2 - Q2 c tr D) in compression (tr D < 0), else 0."""
    if tr_d >= 0.0:
        return 0.0
    return rho * length * (q1 * q1 * length * tr_d * tr_d - q2 * c * tr_d)


@njit(cache=True, inline="always")
def effective_speed(c, tr_d, length, q1, q2):
    """Q + sqrt(Q^2 + c^2), Q = Q2 c + Q1^2 l |tr D| in compression: the speed that bounds
    the explicit step with artificial viscosity (module docstring)."""
    if tr_d >= 0.0:
        return c
    Q = q2 * c + q1 * q1 * length * (-tr_d)
    return Q + math.sqrt(Q * Q + c * c)


@njit(cache=True, inline="always")
def energy_update(p0, J0, J1, E0, w_dev, q, kind, rho0, c0, s, gamma0, K):
    """(E^{n+1}, p^{n+1}) from the trapezoidal energy balance of the module docstring, given
    p0 = p(J0, E0); NaN when the EOS is singular at J1."""
    pc1, _ = pressure(J1, 0.0, kind, rho0, c0, s, gamma0, K)
    dJ = J1 - J0
    g = gamma0 if kind == MIE_GRUNEISEN else 0.0
    E1 = (E0 + w_dev - dJ * (0.5 * (p0 + pc1) + q)) / (1.0 + 0.5 * g * dJ)
    return E1, pc1 + g * E1


@njit(cache=True, inline="always")
def volume_step(J0, E0, ratio, tr_d, dt, s_dot_d, shear, kind, rho0, c0, s, gamma0, K, length,
                q1, q2):
    """(J^{n+1}, E^{n+1}, p^{n+1}) over dt: J <- det(I + dt L) J (``ratio``; the volume change
    of the step's map x + dt v(x), as the engine advances F), q from the start-of-step sound
    speed, the trapezoidal energy balance with the deviatoric work dt J_mid s:D (``s_dot_d``
    = s:D). p is NaN where the EOS failed (or J <= 0)."""
    J1 = J0 * ratio
    p0, dp0 = pressure(J0, E0, kind, rho0, c0, s, gamma0, K)
    c = math.sqrt(sound_speed_sq(J0, p0, dp0, kind, rho0, gamma0, shear))
    q = artificial_viscosity(rho0 / J1, tr_d, c, length, q1, q2)
    w_dev = dt * 0.5 * (J0 + J1) * s_dot_d
    E1, p1 = energy_update(p0, J0, J1, E0, w_dev, q, kind, rho0, c0, s, gamma0, K)
    return J1, E1, p1


@njit(cache=True, inline="always")
def record_failure(p, J1, nbad, bad_index, bad_J):
    """Note particle row p (its J1) among the first reported failures; returns nbad + 1."""
    if nbad < bad_index.shape[0]:
        bad_index[nbad] = p
        bad_J[nbad] = J1
    return nbad + 1


@njit(cache=True, inline="always")
def total_pressure(J, E, tr_d, shear, kind, rho0, c0, s, gamma0, K, length, q1, q2):
    """p(J, E) + q(tr D): the isotropic part of -sigma for the stress kernels."""
    pr, dp = pressure(J, E, kind, rho0, c0, s, gamma0, K)
    c = math.sqrt(sound_speed_sq(J, pr, dp, kind, rho0, gamma0, shear))
    return pr + artificial_viscosity(rho0 / J, tr_d, c, length, q1, q2)


@njit(cache=True)
def pressure_batch(J, E, kind, rho0, c0, s, gamma0, K, p, dp_dzeta):
    """p and dp/dzeta for arrays J, E (n,) (diagnostics and tests)."""
    for i in range(J.shape[0]):
        p[i], dp_dzeta[i] = pressure(J[i], E[i], kind, rho0, c0, s, gamma0, K)


class Volumetric:
    """The volumetric response of an impact material: a Mie-Grüneisen EOS (``eos`` table) or
    p = -K ln J, with the artificial-viscosity coefficients. ``args`` is the tuple the
    kernels take: (kind, rho0, c0, s, gamma0, K)."""

    def __init__(self, eos: dict | None, density: float, bulk_modulus: float,
                 q1: float | None, q2: float | None):
        if eos is None:
            self.kind, self.c0, self.s, self.gamma0 = LOG_BULK, 0.0, 0.0, 0.0
        else:
            self.kind, self.c0, self.s, self.gamma0 = (MIE_GRUNEISEN, eos["c0"], eos["s"],
                                                       eos["gamma0"])
        self.rho0 = density
        self.K = bulk_modulus if eos is None else density * self.c0 * self.c0
        on = eos is not None
        self.q1 = (1.5 if on else 0.0) if q1 is None else q1
        self.q2 = (0.06 if on else 0.0) if q2 is None else q2
        self.args = (self.kind, self.rho0, self.c0, self.s, self.gamma0, self.K)

    @property
    def viscous(self) -> bool:
        return self.q1 > 0.0 or self.q2 > 0.0

    def pressure(self, J: np.ndarray, E: np.ndarray) -> np.ndarray:
        """p(J, E) for arrays (NaN where the EOS is singular)."""
        J = np.ascontiguousarray(J, dtype=np.float64).reshape(-1)
        E = np.ascontiguousarray(np.broadcast_to(E, J.shape), dtype=np.float64)
        p, dp = np.empty_like(J), np.empty_like(J)
        pressure_batch(J, E, *self.args, p, dp)
        return p

    def singular_zeta(self) -> float:
        """The compression zeta at which the failure check fires (inf without an EOS)."""
        if self.kind == LOG_BULK:
            return math.inf
        return (1.0 - MIN_DENOMINATOR) / (self.s - 1.0)


def failure_messages(material_name: str, ids: np.ndarray, J_before: np.ndarray,
                     nbad: int, volumetric: Volumetric) -> list[str]:
    """One line per reported failure: particle id, the state reached, what it means.
    ``J_before`` holds the volume ratio the failing update produced (NaN is written after)."""
    out = []
    for k in range(min(nbad, len(ids))):
        J = float(J_before[k])
        if not J > 0.0:
            out.append(f"material {material_name!r}: particle {int(ids[k])}: volume ratio "
                       f"J = {J:.6g} <= 0 (the particle inverted)")
            continue
        zeta = 1.0 / J - 1.0
        x = 1.0 - (volumetric.s - 1.0) * zeta
        if volumetric.kind == LOG_BULK or x >= MIN_DENOMINATOR:
            # Not the singular compression: the pressure or energy left the floats (measured:
            # a fuzzed eos.gamma0 of 2e300 on cu_shock_column_2d was reported as singular at
            # 1 - (S - 1) zeta = 0.981).
            values = "E, nu" if volumetric.kind == LOG_BULK else \
                "equation-of-state values (eos.gamma0, eos.c0)"
            out.append(f"material {material_name!r}: particle {int(ids[k])}: the pressure "
                       f"or energy is no longer finite at J = {J:.6g} (check the "
                       f"material's {values} and density)")
            continue
        out.append(f"material {material_name!r}: particle {int(ids[k])}: Mie-Gruneisen EOS "
                   f"singular: zeta = {zeta:.6g} (rho/rho0 = {1.0 + zeta:.6g}) gives "
                   f"1 - (S - 1) zeta = {x:.3g} < {MIN_DENOMINATOR:g}; the EOS holds for "
                   f"zeta < {volumetric.singular_zeta():.6g} (lower the impact speed, refine "
                   f"the grid or check eos.s)")
    if nbad > len(ids):
        out.append(f"material {material_name!r}: {nbad - len(ids)} more particle(s) failed "
                   f"the same way")
    return out

"""Mie-Grüneisen EOS, artificial viscosity, the energy update and the parameter schema of the
impact models (hpcmpm/materials/eos.py; 003 §7.2.3 with the issue's corrections)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hpcmpm.errors import InstabilityError, SceneError
from hpcmpm.materials import make_material, validate_params
from hpcmpm.materials.driver import MaterialPoint
from hpcmpm.materials.eos import (LOG_BULK, MIN_DENOMINATOR, Volumetric, artificial_viscosity,
                                  effective_speed, energy_update, pressure, sound_speed_sq,
                                  volume_step)
from hpcmpm.scene import MaterialSpec

# OFHC copper (Marsh, LASL Shock Hugoniot Data 1980; the issue's values).
RHO0, C0, S, GAMMA0 = 8930.0, 3940.0, 1.49, 2.0
CU_EOS = {"type": "mie_gruneisen", "c0": C0, "s": S, "gamma0": GAMMA0}


def spec(type_: str, params: dict) -> MaterialSpec:
    return MaterialSpec("cu", type_, RHO0, params)


def cu() -> Volumetric:
    return Volumetric({"c0": C0, "s": S, "gamma0": GAMMA0}, RHO0, 0.0, None, None)


def hugoniot(u_p: float) -> tuple[float, float, float]:
    """(J, E, p) behind a steady shock of particle speed u_p into copper at rest, from the
    jump conditions alone: U_s = c0 + S u_p (the linear U_s-u_p fit the EOS is built on),
    mass rho0 U_s = rho (U_s - u_p), momentum p = rho0 U_s u_p, energy (per reference
    volume) E = rho0 u_p^2 / 2."""
    U_s = C0 + S * u_p
    return (U_s - u_p) / U_s, 0.5 * RHO0 * u_p ** 2, RHO0 * U_s * u_p


@pytest.mark.parametrize("u_p", [100.0, 500.0, 1000.0])
def test_pressure_on_the_hugoniot(u_p):
    J, E, p_H = hugoniot(u_p)
    p = cu().pressure(np.array([J]), np.array([E]))[0]
    # Closed forms evaluated in a different order: a few ulps of relative round-off.
    assert abs(p - p_H) <= 1e-12 * p_H, (u_p, p, p_H)


def test_the_issues_copper_numbers():
    # The issue quotes, at u_p = 500 m/s: U_s = 4685 m/s, p = 20.92 GPa, rho/rho0 = 1.1195
    # (4 significant figures).
    J, _, p_H = hugoniot(500.0)
    assert C0 + S * 500.0 == 4685.0
    assert round(p_H / 1e9, 2) == 20.92 and round(1 / J, 4) == 1.1195
    # The printed denominator [1 + (S - 1) zeta]^2 gives 17.0 GPa (why it is corrected).
    zeta = 1 / J - 1
    printed = RHO0 * C0 ** 2 * zeta * (1 + (1 - GAMMA0 / 2) * zeta) / (1 + (S - 1) * zeta) ** 2 \
        + GAMMA0 * 0.5 * RHO0 * 500.0 ** 2
    assert round(printed / 1e9, 1) == 17.0


@pytest.mark.parametrize("J", [0.7, 0.95, 1.0 - 1e-3, 1.0 + 1e-3, 1.2])
def test_pressure_slope_is_its_derivative(J):
    """dp/dzeta|_E returned by the kernel against a central difference (error O(h^2))."""
    E = 3e8
    p, dp = pressure(J, E, *cu().args)
    zeta = 1 / J - 1
    h = 1e-5
    plus = pressure(1 / (1 + zeta + h), E, *cu().args)[0]
    minus = pressure(1 / (1 + zeta - h), E, *cu().args)[0]
    # Truncation ~ p''' h^2/6 ~ rho0 c0^2 h^2 ~ 1e1 against dp ~ 1e11; round-off
    # ~ 1e-16 p / h ~ 1e2: both below 1e-8 relative.
    assert abs((plus - minus) / (2 * h) - dp) <= 1e-8 * abs(dp)


@pytest.mark.parametrize("J", [0.8, 0.93, 1.0, 1.1])
def test_sound_speed_is_the_isentropic_slope(J):
    """c^2 - shear/rho = dp/drho along the isentrope dE = -p dJ (E per reference volume):
    the thermodynamic definition, checked by a central difference that carries E along."""
    vol = cu()
    E = 2e8
    p, dp = pressure(J, E, *vol.args)
    c2 = sound_speed_sq(J, p, dp, vol.kind, RHO0, GAMMA0, 0.0)
    h = 1e-6
    # E(J +- h) = E -+ p h + O(h^2); the O(h^2) terms are equal on both sides and cancel.
    p_plus = pressure(J + h, E - p * h, *vol.args)[0]
    p_minus = pressure(J - h, E + p * h, *vol.args)[0]
    rho = lambda j: RHO0 / j  # noqa: E731
    slope = (p_plus - p_minus) / (rho(J + h) - rho(J - h))
    # Central difference O(h^2) ~ 1e-12 relative; round-off ~ 1e-16 p/(rho h) ~ 1e-7 of c^2
    # at the largest p here.
    assert abs(slope - c2) <= 1e-6 * c2, (J, slope, c2)
    # At rest c = c0: the EOS's bulk speed.
    p0, dp0 = pressure(1.0, 0.0, *vol.args)
    assert sound_speed_sq(1.0, p0, dp0, vol.kind, RHO0, GAMMA0, 0.0) == pytest.approx(C0 ** 2,
                                                                                       rel=1e-15)


@pytest.mark.parametrize("J", [0.8, 0.95, 1.05, 1.2])
def test_log_bulk_pressure_and_sound_speed(J):
    """Without an EOS (the J2 model's default) p = -K ln J, independent of E, and c^2 is
    dp/drho (central difference in J; E plays no part, Gamma0 = 0), so the time step sees
    the stiffening K J / rho0 of the Hencky pressure, not K / rho0."""
    K = 1.4e11
    vol = Volumetric(None, RHO0, K, None, None)
    p, dp = pressure(J, 5e8, *vol.args)
    assert p == pytest.approx(-K * math.log(J), rel=1e-15)
    c2 = sound_speed_sq(J, p, dp, vol.kind, RHO0, vol.gamma0, 0.0)
    h = 1e-6
    slope = (pressure(J + h, 0.0, *vol.args)[0] - pressure(J - h, 0.0, *vol.args)[0]) / \
        (RHO0 / (J + h) - RHO0 / (J - h))
    # Central difference O(h^2) ~ 1e-12 relative; round-off 1e-16 / h ~ 1e-10; measured
    # <= 2.3e-11.
    assert abs(slope - c2) <= 1e-8 * c2, (J, slope, c2)


def test_singular_zeta_is_where_the_pressure_fails():
    """The compression the failure message names as the EOS's limit (`singular_zeta`) is the
    one where the pressure turns NaN: finite 1e-9 below it, NaN 1e-9 above (the margin
    moves 1 - (S - 1) zeta by ~1e-9, far above the round-off of J = 1/(1 + zeta))."""
    vol = cu()
    z = vol.singular_zeta()
    below, above = vol.pressure(1 / (1 + z * np.array([1 - 1e-9, 1 + 1e-9])), 0.0)
    assert np.isfinite(below) and np.isnan(above)
    assert Volumetric(None, RHO0, 1e11, None, None).singular_zeta() == math.inf


def test_deviatoric_work_is_integrated_to_second_order():
    """`volume_step` adds the deviatoric work dt J s:D per reference volume with J at the
    middle of the step, (J^n + J^{n+1})/2. Over a steady expansion J = exp(a t) with constant
    s:D, no pressure (K = 0) and no viscosity, the sum is the trapezoid rule for
    int_0^T J s:D dt = s:D (e^{aT} - 1)/a: its error falls as dt^2, a ratio of 4 when dt
    halves (J^n alone: 1.997). Measured 3.99998; 1e-2 is a wide margin."""
    a, T, sd = 2.0, 0.5, 3.0
    exact = sd * math.expm1(a * T) / a
    errors = []
    for n in (50, 100):
        dt = T / n
        J, E = 1.0, 0.0
        for _ in range(n):
            J, E, _ = volume_step(J, E, math.exp(a * dt), a, dt, sd, 0.0, LOG_BULK, RHO0, 0.0,
                                  0.0, 0.0, 0.0, 1e-3, 0.0, 0.0)
        errors.append(E - exact)
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=1e-2)


def test_artificial_viscosity():
    rho, c, length = 9000.0, 4000.0, 1e-3
    assert artificial_viscosity(rho, 0.0, c, length, 1.5, 0.06) == 0.0
    assert artificial_viscosity(rho, 5e4, c, length, 1.5, 0.06) == 0.0  # expansion
    tr_d = -2e5
    q = artificial_viscosity(rho, tr_d, c, length, 1.5, 0.06)
    assert q == pytest.approx(rho * length * (2.25 * length * tr_d ** 2 + 0.06 * c * -tr_d),
                              rel=1e-15)
    # The time step's speed: c without compression, Q + sqrt(Q^2 + c^2) with it.
    assert effective_speed(c, 1.0, length, 1.5, 0.06) == c
    Q = 0.06 * c + 2.25 * length * 2e5
    assert effective_speed(c, tr_d, length, 1.5, 0.06) == pytest.approx(Q + math.hypot(Q, c),
                                                                          rel=1e-15)


@pytest.mark.parametrize("u_p", [100.0, 500.0, 1000.0])
def test_energy_update_lands_on_the_hugoniot(u_p):
    """One jump from rest to the shocked volume with the trapezoidal energy balance gives the
    Rankine-Hugoniot energy (p0 + p)/2 (J0 - J) = rho0 u_p^2/2, hence the Hugoniot pressure."""
    J, E_H, p_H = hugoniot(u_p)
    E1, p1 = energy_update(0.0, 1.0, J, 0.0, 0.0, 0.0, *cu().args)
    # E1 solves a linear equation whose terms are O(p_H): relative round-off of a few ulps.
    assert abs(E1 - E_H) <= 1e-12 * E_H and abs(p1 - p_H) <= 1e-12 * p_H


def shock_point(dim: int, n: int = 1, **extra) -> MaterialPoint:
    params = {"E": 0.0, "nu": 0.3, "eos": CU_EOS, **extra}
    return MaterialPoint(make_material(spec("shock", params), dim), n, dx=1e-3)


@pytest.mark.parametrize("dim", [2, 3])
def test_singular_compression_is_reported(dim):
    mp = shock_point(dim, 3)
    mp.fields["id"][:] = [7, 8, 9]
    zeta_limit = (1 - MIN_DENOMINATOR) / (S - 1)
    # Compress particle 8 past the limit in one step, the others mildly.
    L = np.zeros((3, dim, dim))
    J_target = [0.9, 1 / (1 + 1.01 * zeta_limit), 0.9]
    dt = 1e-6
    for k in range(3):
        L[k, 0, 0] = (J_target[k] - 1) / dt  # det(I + dt L) = J_target
    with pytest.raises(InstabilityError) as err:
        mp.step(L, dt)
    message = str(err.value)
    assert "particle 8" in message and "Mie-Gruneisen EOS singular" in message
    assert f"zeta = {1.01 * zeta_limit:.6g}" in message and "particle 7" not in message
    assert math.isnan(mp.fields["J"][1]) and np.isfinite(mp.fields["J"][[0, 2]]).all()


@pytest.mark.parametrize("dim", [2, 3])
def test_a_pressure_beyond_the_floats_is_not_reported_as_singular(dim):
    """A fuzzed Grueneisen parameter of 2e300: Gamma0 E overflows at a mild compression, far
    from the singular one, and the message said "singular: ... 1 - (S - 1) zeta = 0.981 <
    0.01", a condition that did not hold. It now names what happened."""
    mp = shock_point(dim, 2, eos={**CU_EOS, "gamma0": 2e300})
    mp.fields["id"][:] = [3, 4]
    mp.fields["E"][:] = 1e10      # an energy already deposited (J/m^3): Gamma0 E = inf
    L = np.zeros((2, dim, dim))
    L[:, 0, 0] = (0.97 - 1.0) / 1e-6  # det(I + dt L) = 0.97: zeta = 0.031, x = 0.985
    with pytest.raises(InstabilityError) as err:
        mp.step(L, 1e-6)
    message = str(err.value)
    assert "particle 3: the pressure or energy is no longer finite at J = 0.97" in message
    assert "singular" not in message and "eos.gamma0" in message


def test_parameter_errors_are_one_line_each():
    jc = {"type": "johnson_cook", "A": 90e6, "B": 292e6, "n": 0.31, "C": 0.025}
    assert validate_params("j2", {"E": 1e9, "nu": 0.3, "hardening": jc, "eos": CU_EOS}) == []
    assert validate_params("shock", {"E": 1e9, "nu": 0.3, "eos": {**CU_EOS, "s": 1.0}}) == \
        ["eos.s: must be > 1, got 1"]
    assert validate_params("shock", {"E": 1e9, "nu": 0.3,
                                     "eos": {**CU_EOS, "c0": -1.0, "type": "tillotson"}}) == \
        ["eos.type: unknown value 'tillotson' (valid: mie_gruneisen)",
         "eos.c0: must be > 0, got -1"]
    assert validate_params("j2", {"E": 1e9, "nu": 0.3, "hardening": {**jc, "n": -0.1,
                                                                     "C": -1}}) == \
        ["hardening.n: must be >= 0, got -0.1", "hardening.C: must be >= 0, got -1"]
    assert validate_params("j2", {"E": 1e9, "nu": 0.3, "hardening": jc,
                                  "return_map": "radial"}) == \
        ["return_map: unknown value 'radial' (valid: newton, linearized)"]
    assert validate_params("shock", {"E": 1e9, "nu": 0.3, "eos": 3.0}) == \
        ["eos: must be a table ({key = value, ...}), got float 3.0"]
    assert validate_params("shock", {"E": 1e9, "nu": 0.3}) == ["eos: missing"]
    assert validate_params("j2", {"E": 1e9, "nu": 0.3, "hardening": {**jc, "AA": 1}}) == \
        ["hardening.AA: unknown key (did you mean 'A'?)"]
    with pytest.raises(SceneError, match="hardening.T_melt: missing"):
        make_material(spec("j2", {"E": 1e9, "nu": 0.3, "hardening": jc,
                                  "specific_heat": 383.0}), 3)


def test_defaults_of_the_eos_and_viscosity():
    mat = make_material(spec("shock", {"E": 1e9, "nu": 0.3,
                                       "eos": {"type": "mie_gruneisen", "c0": 2092.0}}), 3)
    vol = mat.volumetric_response
    assert (vol.s, vol.gamma0, vol.q1, vol.q2) == (1.1, 1.6, 1.5, 0.06)  # 003 §7.2.3
    given = make_material(spec("shock", {"E": 1e9, "nu": 0.3, "eos": CU_EOS, "q1": 0.7,
                                         "q2": 0.2}), 3).volumetric_response
    assert (given.q1, given.q2) == (0.7, 0.2)  # each key reaches its own coefficient
    jc = {"type": "johnson_cook", "A": 1e6}
    plain = make_material(spec("j2", {"E": 1e9, "nu": 0.3, "hardening": jc}), 3)
    assert not plain.volumetric_response.viscous  # no EOS: no viscosity unless asked
    # Without configure(scene) a viscous model refuses to run rather than use l = 0.
    with pytest.raises(RuntimeError, match="configure"):
        mat.update_stress({"L": np.zeros((1, 3, 3)), "F_E": np.eye(3)[None], "J": np.ones(1),
                           "E": np.zeros(1), "tau": np.zeros((1, 3, 3))}, 0.0)

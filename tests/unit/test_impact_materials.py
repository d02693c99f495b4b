"""The "L"-mode impact models at material points: the shock model (003 §7.2.2) and J2 with
Johnson-Cook hardening (003 §7.3, appendix B); hpcmpm/materials/shock.py, j2.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hpcmpm.materials import lame, make_material
from hpcmpm.materials.driver import MaterialPoint
from hpcmpm.materials.eos import pressure
from hpcmpm.materials.j2 import cayley3, jc_yield, thermal_factor
from hpcmpm.scene import MaterialSpec

DIMS = (2, 3)
RHO0 = 8930.0
CU_EOS = {"type": "mie_gruneisen", "c0": 3940.0, "s": 1.49, "gamma0": 2.0}
# Wilkins & Guinan 1973 OFHC copper with Johnson-Cook 1983 constants (the Taylor bar).
E_CU, NU_CU = 124e9, 0.34
JC_CU = {"type": "johnson_cook", "A": 90e6, "B": 292e6, "n": 0.31, "C": 0.025, "m": 1.09,
         "T_melt": 1356.0, "T_room": 293.0}


def spec(type_: str, params: dict) -> MaterialSpec:
    return MaterialSpec("m", type_, RHO0, params)


def shock(dim: int, n: int = 1, **extra) -> MaterialPoint:
    params = {"E": 2e9, "nu": 0.3, "eos": CU_EOS, **extra}
    return MaterialPoint(make_material(spec("shock", params), dim), n, dx=1e-3)


def j2(dim: int, n: int = 1, **extra) -> MaterialPoint:
    params = {"E": E_CU, "nu": NU_CU, "hardening": JC_CU, **extra}
    return MaterialPoint(make_material(spec("j2", params), dim), n, dx=1e-3)


# -- shock model -----------------------------------------------------------------------------
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("clamp", [{}, {"theta_c": 0.05, "theta_s": 0.015}])
def test_shock_model_is_stress_free_at_rest(dim, clamp):
    mp = shock(dim, 4, **clamp)
    for _ in range(3):
        mp.step(np.zeros((dim, dim)), 1e-7)
    # Exactly: dev(b) of F_E = I, p(1, 0) and q(tr D = 0) are all exact zeros.
    assert np.all(mp.fields["tau"] == 0.0) and np.all(mp.fields["E"] == 0.0)


@pytest.mark.parametrize("dim", DIMS)
def test_shock_model_pure_dilatation_is_minus_p_identity(dim):
    """F_E = a I, J = a^d, E given: sigma = -p(J, E) I exactly (no deviator, q off since the
    stored L is 0); p from the EOS formula written out here."""
    mp = shock(dim, 3)
    a = np.array([0.97, 1.0, 1.02])
    J = a ** dim
    E = np.array([1e8, 0.0, 5e7])
    mp.fields["F_E"][:] = a[:, None, None] * np.eye(dim)
    mp.fields["J"][:] = J
    mp.fields["E"][:] = E
    mp.material.update_stress(mp.fields, 1e-7)
    zeta = 1 / J - 1
    k0 = RHO0 * CU_EOS["c0"] ** 2
    g, s = CU_EOS["gamma0"], CU_EOS["s"]
    p = np.where(zeta >= 0, k0 * zeta * (1 + (1 - g / 2) * zeta) / (1 - (s - 1) * zeta) ** 2,
                 k0 * zeta) + g * E
    sigma = mp.cauchy()
    # Exactly a multiple of I: dev(a^2 I) is an exact zero in the kernel.
    assert np.all(sigma == sigma[:, :1, :1] * np.eye(dim))
    # The diagonal is J (-p) / J: round-off of the EOS arithmetic (~1e-15 relative).
    assert np.allclose(np.einsum("nii->ni", sigma), -p[:, None], rtol=1e-14, atol=0)


@pytest.mark.parametrize("dim", DIMS)
def test_shock_model_small_shear_is_hookean(dim):
    """Simple shear gamma: sigma_xy = mu gamma + O(gamma^2) with mu = E/(2(1 + nu)), the
    stable Neo-Hookean reparameterisation carried into the shock model's deviator."""
    mp = shock(dim)
    gamma, steps = 1e-4, 10
    L = np.zeros((dim, dim))
    L[0, 1] = gamma / (steps * 1e-7)
    for _ in range(steps):
        mp.step(L, 1e-7)
    mu, _ = lame(2e9, 0.3)
    # Relative error O(gamma) = 1e-4 from the nonlinearity.
    assert mp.cauchy()[0, 0, 1] == pytest.approx(mu * gamma, rel=5e-4)


@pytest.mark.parametrize("dim", DIMS)
def test_shock_model_clamp_bounds_elastic_stretch(dim):
    mp = shock(dim, 1, theta_c=0.05, theta_s=0.015)
    L = np.zeros((dim, dim))
    L[0, 0], L[1, 0] = 2e3, 1e3  # stretch and shear far past the clamp
    for _ in range(200):
        mp.step(L, 1e-6)
    sv = np.linalg.svd(mp.fields["F_E"][0], compute_uv=False)
    # Clamped to the interval up to the round-off of rebuilding U Sigma V^T.
    assert sv.max() <= 1.015 + 1e-14 and sv.min() >= 0.95 - 1e-14
    # The volume is not clamped: J = det(I + dt L)^steps (200 products: 1e-13).
    assert mp.fields["J"][0] == pytest.approx((1 + 1e-6 * 2e3) ** 200, rel=1e-13)


def cold_pressure(J: np.ndarray) -> np.ndarray:
    """p(J, E = 0) of the corrected 003 eq. 7.4 written out (compressive branch, J <= 1)."""
    zeta = 1 / J - 1
    g, s = CU_EOS["gamma0"], CU_EOS["s"]
    return RHO0 * CU_EOS["c0"] ** 2 * zeta * (1 + (1 - g / 2) * zeta) / (1 - (s - 1) * zeta) ** 2


def compression_work(J: float) -> float:
    """E (per reference volume) after a shear-free squeeze from 1 to J: the solution of the
    energy balance dE = -p dJ (the corrected 003 eq. 7.3 with s:D = 0) with p = p_c(J) +
    Gamma0 E, a linear ODE: E(J) = int_J^1 p_c(J') exp(Gamma0 (J' - J)) dJ'. 40-point
    Gauss-Legendre on a smooth integrand: exact to round-off."""
    x, w = np.polynomial.legendre.leggauss(40)
    Jq = J + (1 - J) * (x + 1) / 2
    return 0.5 * (1 - J) * float(np.sum(w * cold_pressure(Jq)
                                        * np.exp(CU_EOS["gamma0"] * (Jq - J))))


@pytest.mark.parametrize("dim", DIMS)
def test_shock_model_energy_is_the_stress_work(dim):
    """A slow compress-release cycle to J = 0.9 without viscosity, at dt and dt/2. At peak
    compression E is the work -int p dJ (corrected 003 eq. 7.3; F_E stays isotropic, so no
    deviatoric work) up to the trapezoid's O(dt^2) error, which the two runs measure. After
    the release E is back at 0 to round-off: the trapezoid is time-symmetric, so retracing
    the same J nodes undoes each step exactly (no O(dt^2) residual)."""
    J_peak, dt0 = 0.9, 1e-6
    errors = []
    for n in (100, 200):  # steps each way; dt = dt0 * 100 / n, the same strain rate
        dt = dt0 * 100 / n
        mp = shock(dim, 1, q1=0.0, q2=0.0)
        a = J_peak ** (1 / (dim * n))  # each compression step scales lengths by a
        for g in ((a - 1) / dt, (1 / a - 1) / dt):
            for _ in range(n):
                mp.step(g * np.eye(dim), dt)
            if g < 0:
                J1, E1 = mp.fields["J"][0], mp.fields["E"][0]
        work = compression_work(J1)  # at the J reached (J_peak up to round-off)
        errors.append(E1 / work - 1)
        # 2n steps, each up to 2d roundings of 1.1e-16 (the factors 1 + dt g, the
        # determinant's products, J's product); measured <= 2.8e-14.
        assert abs(mp.fields["J"][0] - 1) < 2 * n * 2 * dim * 1.2e-16
        # Measured |E| <= 1.1e-15 E_peak (round-off only); 1e-13 leaves a 100x margin.
        assert abs(mp.fields["E"][0]) < 1e-13 * work
    # The trapezoid's global error -h^2/12 [dp/dJ] with h = dJ per step is, for a linear EOS,
    # 1/(6 n^2) = 1.7e-5 of the work at n = 100; measured +1.2009e-5 in 2D and 3D (only the J
    # path matters, and it is the same). 2e-5 bounds it; an E that is not updated misses by 1.
    assert 0 < errors[0] < 2e-5
    # Measured ratio 4.0000032 (next order O(1/n^2) ~ 1e-6); the errors sit 1e9 above the
    # round-off of E, so 1e-4 is a 100x margin.
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=1e-4)


@pytest.mark.parametrize("dim", DIMS)
def test_max_wave_speed(dim):
    mp = shock(dim, 2)
    mat = mp.material
    mu, _ = lame(2e9, 0.3)
    shear = (1.0 if dim == 2 else 4 / 3) * mu
    assert mat.wave_speed() == pytest.approx(math.sqrt(3940.0 ** 2 + shear / RHO0), rel=1e-15)
    assert mat.max_wave_speed(mp.fields) == pytest.approx(mat.wave_speed(), rel=1e-15)
    mp.fields["J"][1] = 0.9
    mp.fields["L"][1] = -1e5 * np.eye(dim)
    p, dp = pressure(0.9, 0.0, *mat.volumetric_response.args)
    c = math.sqrt((dp + 2.0 * p * 0.81 + shear * 0.9) / RHO0)
    Q = 0.06 * c + 2.25 * 1e-3 * 1e5 * dim
    assert mat.max_wave_speed(mp.fields) == pytest.approx(Q + math.hypot(Q, c), rel=1e-14)


# -- J2 / Johnson-Cook -----------------------------------------------------------------------
def test_cayley_rotation():
    rng = np.random.default_rng(1)
    for _ in range(5):
        w = rng.normal(size=3)
        Om = np.array([[0, w[0], w[1]], [-w[0], 0, w[2]], [-w[1], -w[2], 0]])
        R = np.array(cayley3(*w)).reshape(3, 3)
        # The closed form against the definition; O(1) entries: round-off 1e-15.
        assert np.allclose(R, np.linalg.solve(np.eye(3) - Om, np.eye(3) + Om), atol=1e-14)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-15)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("extra", [{}, {"specific_heat": 383.0},
                                   {"eos": CU_EOS, "return_map": "newton"}])
def test_return_lands_on_the_yield_surface(dim, extra):
    """After the return |sqrt(3/2)|s| - sigma_y(eps_p, d/dt, T^n)| <= 1e-10 sigma_y (the
    Newton tolerance) for random strain increments from small to 50 x the yield strain."""
    rng = np.random.default_rng(dim)
    n = 200
    mp = j2(dim, n, **extra)
    mat = mp.material
    mp.fields["eps_p"][:] = np.where(rng.random(n) < 0.3, 0.0, rng.uniform(0, 0.5, n))
    if "T" in mp.fields:
        mp.fields["T"][:] = rng.uniform(293, 900, n)
    dt = 1e-6
    L = rng.normal(size=(n, dim, dim)) * np.logspace(-1, 1.7, n)[:, None, None] * \
        (90e6 / E_CU) / dt
    eps0, T0 = mp.fields["eps_p"].copy(), mp.fields.get("T", np.full(n, 293.0)).copy()
    mp.step(L, dt)
    s = mp.fields["s"]
    s2 = np.einsum("nij,nij->n", s, s) + (mp.fields["s_zz"] ** 2 if dim == 2 else 0)
    s_eq = np.sqrt(1.5 * s2)
    d = mp.fields["eps_p"] - eps0
    plastic = d > 0
    assert plastic.sum() > n // 2  # most of them yield, so the check has teeth
    sy = np.array([mat.yield_stress(e, dd / dt, T) for e, dd, T in
                   zip(mp.fields["eps_p"], d, T0)])
    assert np.all(np.abs(s_eq[plastic] - sy[plastic]) <= 1e-10 * sy[plastic])
    assert np.all(s_eq[~plastic] <= sy[~plastic] * (1 + 1e-15))
    # s is deviatoric (plane strain: s_xx + s_yy + s_zz = 0) and symmetric.
    tr = np.einsum("nii->n", s) + (mp.fields["s_zz"] if dim == 2 else 0)
    assert np.abs(tr).max() <= 1e-12 * s_eq.max()
    assert np.array_equal(s, s.transpose(0, 2, 1))


@pytest.mark.parametrize("dim", DIMS)
def test_quarter_turn_keeps_the_stress(dim):
    """A stressed point spun rigidly by a quarter turn: |s| kept to 1e-12 and s rotated
    with the body (Hughes-Winget's R is a rotation, the Cayley angle is 2 atan(dt w/2))."""
    rng = np.random.default_rng(3)
    mp = j2(dim)
    s0 = rng.normal(size=(dim, dim))
    s0 = s0 + s0.T
    szz = 0.0
    if dim == 2:
        szz = -np.trace(s0)
    else:
        s0 -= np.trace(s0) / 3 * np.eye(3)
    norm = math.sqrt(np.sum(s0 * s0) + szz ** 2)
    s0 *= 0.5 * 90e6 * math.sqrt(2 / 3) / norm  # half the yield stress: stays elastic
    szz *= 0.5 * 90e6 * math.sqrt(2 / 3) / norm
    mp.fields["s"][0] = s0
    if dim == 2:
        mp.fields["s_zz"][0] = szz
    steps, dt = 50, 1e-6
    w = 2 * math.tan(math.pi / 2 / steps / 2) / dt  # Cayley angle per step pi/(2 steps)
    L = np.zeros((dim, dim))
    L[1, 0], L[0, 1] = w, -w  # spin about z, counter-clockwise
    for _ in range(steps):
        mp.step(L, dt)
    s = mp.fields["s"][0]
    size = math.sqrt(np.sum(s * s) + (mp.fields["s_zz"][0] ** 2 if dim == 2 else 0))
    size0 = math.sqrt(np.sum(s0 * s0) + szz ** 2)
    # 50 rotations of a few ulps each.
    assert abs(size - size0) <= 1e-12 * size0
    Q = np.eye(dim)
    Q[:2, :2] = [[0, -1], [1, 0]]
    assert np.allclose(s, Q @ s0 @ Q.T, rtol=0, atol=1e-12 * size0)
    assert mp.fields["eps_p"][0] == 0.0


@pytest.mark.parametrize("dim", DIMS)
def test_j2_small_strain_is_hookean(dim):
    """Below yield, a strain increment eps gives s = 2 mu dev(eps), p = -K tr(eps) to first
    order (plane strain in 2D)."""
    rng = np.random.default_rng(4)
    mp = j2(dim)
    H = rng.normal(size=(dim, dim))
    eps = 1e-5
    mp.step(eps * H / 1e-6, 1e-6)
    mu, lam = lame(E_CU, NU_CU)
    sym = 0.5 * (H + H.T) * eps
    hooke = 2 * mu * (sym - np.trace(sym) / 3 * np.eye(dim)) + \
        (lam + 2 * mu / 3) * np.trace(sym) * np.eye(dim)
    # Relative error O(eps) from ln J vs tr eps.
    assert np.abs(mp.cauchy()[0] - hooke).max() <= 10 * eps * np.abs(hooke).max()


def test_johnson_cook_yield_function():
    """003 eq. 7.7 with the rate factor floored at 1 and Johnson-Cook 1983 softening."""
    A, B, n, C = 90e6, 292e6, 0.31, 0.025
    assert jc_yield(0.2, 1e3, A, B, n, C, 1.0, 1.0) == \
        pytest.approx((A + B * 0.2 ** n) * (1 + C * math.log(1e3)), rel=1e-15)
    assert jc_yield(0.2, 1e-3, A, B, n, C, 1.0, 1.0) == pytest.approx(A + B * 0.2 ** n,
                                                                     rel=1e-15)
    assert jc_yield(0.0, 0.0, A, B, 0.0, C, 1.0, 1.0) == A + B  # n = 0: eps^0 = 1
    assert thermal_factor(293.0, 293.0, 1356.0, 1.09) == 1.0
    assert thermal_factor(824.5, 293.0, 1356.0, 1.09) == pytest.approx(1 - 0.5 ** 1.09)
    assert thermal_factor(2000.0, 293.0, 1356.0, 1.09) == 0.0


def test_adiabatic_heating():
    """dT = 0.9 sigma_y d eps_p/(rho c_v) (Johnson and Cook 1983), summed over the steps."""
    mp = j2(3, specific_heat=383.0)
    dt = 1e-6
    lateral = (1 / math.sqrt(1 + 1e3 * dt) - 1) / dt  # det(I + dt L) = 1: isochoric
    L = np.diag([1e3, lateral, lateral])
    work = 0.0
    for _ in range(200):
        e0, T0 = mp.fields["eps_p"][0], mp.fields["T"][0]
        mp.step(L, dt)
        d = mp.fields["eps_p"][0] - e0
        work += 0.9 * mp.material.yield_stress(mp.fields["eps_p"][0], d / dt, T0) * d
    assert mp.fields["eps_p"][0] > 0.1
    # Isochoric: rho = rho0 (to round-off), so the sum is exact up to round-off.
    assert mp.fields["T"][0] - 293.0 == pytest.approx(work / (RHO0 * 383.0), rel=1e-12)


@pytest.mark.parametrize("n", [0.31, 1.0, 1.7])
def test_johnson_cook_hardening_slope_is_its_derivative(n):
    """jc_hardening's slope (used by the linearized return and the Newton return's Jacobian)
    equals the central difference of B eps^n; step 1e-6 eps: truncation ~1e-12 relative,
    round-off ~1e-10, so 1e-7 separates them from any wrong factor (n, 1/n) by far."""
    from hpcmpm.materials.j2 import jc_hardening

    B = 292e6
    for eps in (1e-3, 0.1, 0.8):
        d = 1e-6 * eps
        numeric = (jc_hardening(eps + d, B, n)[0] - jc_hardening(eps - d, B, n)[0]) / (2 * d)
        assert jc_hardening(eps, B, n)[1] == pytest.approx(numeric, rel=1e-7), eps

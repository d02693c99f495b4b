"""Homogeneous material-point verification of the b_E models (issue 9, "Homogeneous driver"):
Oldroyd-B against the classic closed forms, the steady Herschel-Bulkley flow curve and the von
Mises shear plateau, one material point under a prescribed velocity gradient
(`hpcmpm.materials.driver`).

Units: mu = Wi = 1 (stress and time units), lambda = 10; s = t / Wi, W = (rate) Wi. The closed
forms are those of the classic Oldroyd-B conformation A (upper-convected derivative of A =
(I - A) / Wi, A(0) = I) with the volume-preserving rescale b_E = c A, c = (J^2/det A)^(1/d)
(000 eq. 5.5), and sigma = mu/J (b_E - I) + lam (J - 1) I + 2 mu_N sym L (eq. 5.9-5.11):

    start-up shear L = W e_x e_y^T:  A_xy = W (1 - e^-s), A_xx = 1 + 2 W^2 [1 - (1 + s) e^-s],
                                     other diagonal 1, J = 1
    relaxation L = 0:                A - I = (A0 - I) e^-s
    extension L = diag(l_k):         A_kk = a_k + (1 - a_k) e^-(1 - 2 l_k Wi) s,
                                     a_k = 1/(1 - 2 l_k Wi), J = exp(t tr L)

The error of a run is max over its steps (t > 0) and stress components of |sigma - exact|,
relative to max |exact|. Issue 9: at dt/Wi = 0.01 the error is <= 1 % for W in {0.5, 1},
and its slope in log-log over dt/Wi = 0.04 ... 0.005 is 1 +- 0.1 (the schemes are first
order), 2 +- 0.2 for fe_bdf2 (BDF2). The extension flow's volume ratio J = prod(1 + dt l_k)^n
(000 eq. 5.12, the MPM F update) is itself first order, so there fe_bdf2's *stress* is first
order too; its conformation (the stored b = A, independent of J) is checked for order 2 in
every flow instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from hpcmpm.materials import make_material
from hpcmpm.materials.driver import drive

MU, LAM, WI, MU_N = 1.0, 10.0, 1.0, 0.1
RATIOS = (0.04, 0.02, 0.01, 0.005)  # dt / Wi
PLASTICITIES = ("ob_spd", "ob_explicit", "fe", "fe_bdf2")
WEISSENBERGS = (0.5, 1.0)
# Extension rates l_k = (W / Wi) * EXTENSION[:d]: a compressible flow (tr L != 0) exercising
# J, c and the lam (J - 1) term; l_k Wi < 1/2 keeps A bounded (coil-stretch limit).
EXTENSION = (0.25, -0.125, 0.0625)


@dataclass
class Spec:
    type: str
    params: dict
    density: float = 1.0
    name: str = "m"


def oldroyd_b(dim: int, plasticity: str, viscosity: float = MU_N):
    return make_material(Spec("oldroyd_b", {"mu": MU, "lambda": LAM, "relaxation_time": WI,
                                            "viscosity": viscosity, "plasticity": plasticity}),
                         dim)


def stress_from_conformation(A: np.ndarray, J: np.ndarray, dim: int) -> np.ndarray:
    """sigma_E of 000 eq. 5.9 with b_E = c A; A (n, d, d), J (n,)."""
    c = (J**2 / np.linalg.det(A)) ** (1.0 / dim)
    return MU / J[:, None, None] * (c[:, None, None] * A - np.eye(dim)) + \
        (LAM * (J - 1.0))[:, None, None] * np.eye(dim)


def flow(name: str, dim: int, W: float):
    """(L (d, d), initial conformation A0 (d, d), end time, exact(t) -> (A, J, sigma))."""
    eye = np.eye(dim)
    if name == "startup_shear":
        L = np.zeros((dim, dim))
        L[0, 1] = W / WI

        def exact(t):
            s = t / WI
            A = np.tile(eye, (len(t), 1, 1))
            A[:, 0, 1] = A[:, 1, 0] = W * (1.0 - np.exp(-s))
            A[:, 0, 0] = 1.0 + 2.0 * W**2 * (1.0 - (1.0 + s) * np.exp(-s))
            J = np.ones_like(t)
            sigma = stress_from_conformation(A, J, dim) + MU_N * (L + L.T)
            return A, J, sigma
        return L, eye, 3.0 * WI, exact
    if name == "relaxation":
        # From the steady-shear conformation at this W.
        A0 = eye.copy()
        A0[0, 1] = A0[1, 0] = W
        A0[0, 0] = 1.0 + 2.0 * W**2

        def exact(t):
            A = eye + (A0 - eye) * np.exp(-t / WI)[:, None, None]
            J = np.ones_like(t)
            return A, J, stress_from_conformation(A, J, dim)
        return np.zeros((dim, dim)), A0, 2.0 * WI, exact
    l = (W / WI) * np.array(EXTENSION[:dim])

    def exact(t):
        a = 1.0 / (1.0 - 2.0 * l * WI)
        diag = a + (1.0 - a) * np.exp(-(1.0 - 2.0 * l * WI)[None, :] * (t / WI)[:, None])
        A = diag[:, :, None] * eye
        J = np.exp(t * l.sum())
        return A, J, stress_from_conformation(A, J, dim) + MU_N * 2.0 * np.diag(l)
    return np.diag(l), eye, 2.0 * WI, exact


def run(name: str, plasticity: str, dim: int, W: float, ratio: float):
    """(stress error, conformation error) of one run (module docstring)."""
    L, A0, end, exact = flow(name, dim, W)
    mat = oldroyd_b(dim, plasticity)
    state = {"b": A0}
    if plasticity in ("fe", "fe_bdf2"):
        state["Fe"] = np.linalg.cholesky(A0)  # any F_E with F_E F_E^T = A0
    dt = ratio * WI
    res = drive(mat, lambda t: L, dt, int(round(end / dt)), state=state, record=("b",))
    t = res.time[1:]  # at t = 0 the stored L is zero: the start-up's viscous jump is not there
    A, J, sigma = exact(t)
    stress_error = np.abs(res.sigma()[1:, 0] - sigma).max() / np.abs(sigma).max()
    conformation_error = np.abs(res.history["b"][1:, 0] - A).max() / np.abs(A).max()
    return stress_error, conformation_error


def slope(errors) -> float:
    return float(np.polyfit(np.log(RATIOS), np.log(errors), 1)[0])


# Measured stress error at dt/Wi = 0.01, the largest over dim in {2, 3} and W in {0.5, 1} of
# each flow and plasticity (rounded up to two digits); each run must stay within 1.5x of it.
# The 1 % alone lets a first-order-consistent error through: ob_explicit with
# R = (1 - r) b^n instead of b^n (a mutant) measured 1.02 %-1.61 % in start-up shear, against
# 0.24 % here (its relaxation is unchanged and its extension, 0.43 % against 0.31 %, stays
# within the bound).
MEASURED_AT_0_01 = {
    "startup_shear": {"ob_spd": 2.1e-3, "ob_explicit": 2.5e-3, "fe": 3.4e-3, "fe_bdf2": 7.4e-5},
    "relaxation": {"ob_spd": 1.9e-3, "ob_explicit": 1.9e-3, "fe": 1.8e-3, "fe_bdf2": 8.8e-5},
    "extension": {"ob_spd": 3.3e-3, "ob_explicit": 3.2e-3, "fe": 3.2e-3, "fe_bdf2": 3.1e-3},
}


@pytest.mark.parametrize("dim", (2, 3))
@pytest.mark.parametrize("plasticity", PLASTICITIES)
@pytest.mark.parametrize("name", ("startup_shear", "relaxation", "extension"))
def test_oldroyd_b_closed_forms(name, plasticity, dim):
    for W in WEISSENBERGS:
        errors = np.array([run(name, plasticity, dim, W, r) for r in RATIOS])
        stress, conformation = errors[:, 0], errors[:, 1]
        # Issue 9's bar: 1 % at dt/Wi = 0.01 (measured 0.07 %-0.33 %, see the report).
        assert stress[RATIOS.index(0.01)] <= 0.01, (name, plasticity, dim, W, stress)
        # And this scheme's own measured error (fe_bdf2 second order except in the extension
        # flow's J), with a 1.5x margin: MEASURED_AT_0_01.
        assert stress[RATIOS.index(0.01)] <= 1.5 * MEASURED_AT_0_01[name][plasticity], \
            (name, plasticity, dim, W, stress)
        second_order = plasticity == "fe_bdf2"
        # The schemes' orders, 1 (2 for BDF2), with the issue's margin: the four ratios sit in
        # the asymptotic range (measured slopes within 0.02 of 1 and 0.06 of 2).
        stress_order = 2.0 if second_order and name != "extension" else 1.0
        assert abs(slope(stress) - stress_order) <= 0.1 * stress_order, \
            (name, plasticity, dim, W, stress)
        conformation_order = 2.0 if second_order else 1.0
        assert abs(slope(conformation) - conformation_order) <= 0.1 * conformation_order, \
            (name, plasticity, dim, W, conformation)


def test_start_up_shear_normal_stress_and_viscosity():
    """The shear stress carries mu_N gdot and N1 = mu c (A_xx - 1) in 2D (J = 1), separately
    from the combined error above: the components the issue names."""
    W, dt = 1.0, 0.005
    L, _, end, exact = flow("startup_shear", 2, W)
    res = drive(oldroyd_b(2, "ob_spd"), lambda t: L, dt, int(round(end / dt)))
    sigma = res.sigma()[-1, 0]
    s = end / WI
    Axy, Axx = W * (1 - math.exp(-s)), 1 + 2 * W**2 * (1 - (1 + s) * math.exp(-s))
    c = (Axx - Axy**2) ** -0.5
    # First-order error ~0.13 dt/Wi relative (measured), so 0.2 % here.
    assert sigma[0, 1] == pytest.approx(MU * c * Axy + MU_N * W / WI, rel=2e-3)
    assert sigma[0, 0] - sigma[1, 1] == pytest.approx(MU * c * (Axx - 1), rel=2e-3)


def hb_flow_curve(sigma_y, eta, h, rate):
    """tau_y + K gdot^h from the scene's keys (issue 9), written out here rather than taken
    from the material, so a wrong mapping of yield_strain or flow_consistency fails."""
    return MU * sigma_y / math.sqrt(2.0) + MU * eta * 2.0 ** (-(h + 1) / 2) * rate**h


@pytest.mark.parametrize("dim", (2, 3))
@pytest.mark.parametrize("h", (0.5, 1.0, 2.0))
@pytest.mark.parametrize("rate", (0.1, 1.0))
def test_herschel_bulkley_steady_flow_curve(rate, h, dim):
    """Steady simple shear: tau_xy = tau_y + K gdot^h, tau_y = mu sigma_Y / sqrt 2,
    K = mu eta 2^-((h+1)/2) (issue 9; small strain, sigma_Y = eta = 0.01)."""
    mat = make_material(Spec("herschel_bulkley", {
        "mu": MU, "lambda": LAM, "yield_strain": 0.01, "flow_consistency": 0.01,
        "flow_index": h}), dim)
    L = np.zeros((dim, dim))
    L[0, 1] = rate
    # dt rate = 1e-4: the flow rate is evaluated at t^n (explicit), and h = 2 at rate 0.1
    # oscillates at dt rate = 1e-3; the elastic strain ~1e-2 is loaded in ~1e2 steps and the
    # flow relaxes within ~1e3, so 5000 steps reach the steady state.
    dt = 1e-4 / rate
    res = drive(mat, lambda t: L, dt, 5000)
    tau = res.sigma()[:, 0, 0, 1]  # J = 1
    expected = hb_flow_curve(0.01, 0.01, h, rate)
    assert abs(tau[-1] - tau[-1000]) <= 1e-9 * expected  # steady
    # 0.5 % (issue 9). The closed form neglects O(strain^2) ~ 1e-4 terms; measured 0.003 %
    # to 0.02 %.
    assert tau[-1] == pytest.approx(expected, rel=5e-3)


@pytest.mark.parametrize("dim", (2, 3))
def test_von_mises_shear_plateau(dim):
    """Simple shear well past yield: tau_xy -> mu sigma_Y / sqrt 2 (the radial return keeps
    |dev b_bar| = sigma_Y)."""
    sigma_y = 0.01
    mat = make_material(Spec("von_mises", {"mu": MU, "lambda": LAM, "yield_strain": sigma_y}),
                        dim)
    L = np.zeros((dim, dim))
    L[0, 1] = 1.0
    res = drive(mat, lambda t: L, 1e-4, 2000)  # shear strain 0.2, 30x the yield strain
    tau = res.sigma()[:, 0, 0, 1]
    # 0.5 % (issue 9); the plateau differs from the small-strain value by O(sigma_Y^2) ~ 1e-4
    # (measured 3e-5).
    assert tau[-1] == pytest.approx(MU * sigma_y / math.sqrt(2.0), rel=5e-3)
    assert tau[-1] == pytest.approx(tau[-200], rel=1e-6)  # a plateau, not a transient


@pytest.mark.parametrize("dim", (2, 3))
def test_von_mises_shear_plateau_after_compression(dim):
    """The radial return acts on the isochoric b_bar = b / det(b)^(1/d) (000 §4.2.6, §4.3;
    Simo 1988), so it must hold at any J, not only at J = 1 where b = b_bar (the previous
    test). Compress isotropically (L = -I for 1000 steps of 1e-4: J = (1 - dt)^(d 1000),
    0.82 in 2D, 0.74 in 3D), then shear at rate 1 to a strain of 0.2.

    What the code implies. The compression keeps b_bar = I (b_hat = (1 - dt)^2 b), and the
    trial b_hat and the return are unchanged when b is scaled, so b / J^(2/d) follows the
    J = 1 run exactly (measured 4e-15 in 2D, 2e-14 in 3D). The return sets |dev b_bar| =
    sigma_Y with tr b_bar kept, and the stored b is rescaled to det b = J^2, which changes
    |dev(b / J^(2/d))| by a factor det(b_ret)^(-1/d) = 1 - O(sigma_Y dt gdot) (measured
    -7e-7 in 2D, -5e-7 in 3D; tolerance 1e-5). With det b = J^2, b_E = b and eq. 5.9 gives
    sigma_xy = mu b_xy / J = mu J^(2/d - 1) (b / J^(2/d))_xy, so the plateau is
    mu sigma_Y J^(2/d - 1) / sqrt2: independent of J in 2D, but J^(-1/3) = 1.105 times
    mu sigma_Y / sqrt2 in 3D. Measured 1 - 2.6e-5 (2D) and 1 - 3.4e-5 (3D) of it, the
    O(sigma_Y^2) normal part of dev b_bar (as in the previous test); tolerance 1e-4.
    A return that keeps tr(b_hat)/d instead of tr(b_bar)/d (a mutant) gave |dev| 1.22 sigma_Y
    and the plateau 1.22 times this in both dimensions."""
    sigma_y, dt, squeeze, shear_steps = 0.01, 1e-4, 1000, 2000
    mat = make_material(Spec("von_mises", {"mu": MU, "lambda": LAM, "yield_strain": sigma_y}),
                        dim)
    shear = np.zeros((dim, dim))
    shear[0, 1] = 1.0

    def L(t):  # step n uses L(n dt): compression for steps 1 ... squeeze
        return -np.eye(dim) if t < (squeeze + 0.5) * dt else shear

    res = drive(mat, L, dt, squeeze + shear_steps)
    J = res.J[-1, 0]
    assert J == pytest.approx((1.0 - dt) ** (dim * squeeze), rel=1e-12)
    b_bar = res.fields["b"][0] / J ** (2.0 / dim)
    dev = b_bar - np.trace(b_bar) / dim * np.eye(dim)
    assert np.linalg.norm(dev) == pytest.approx(sigma_y, rel=1e-5)
    at_rest_volume = drive(mat, lambda t: shear, dt, shear_steps).fields["b"][0]
    np.testing.assert_allclose(b_bar, at_rest_volume, rtol=0, atol=1e-12)
    tau = res.sigma()[:, 0, 0, 1]
    plateau = MU * sigma_y * J ** (2.0 / dim - 1.0) / math.sqrt(2.0)
    assert tau[-1] == pytest.approx(plateau, rel=1e-4)
    assert tau[-1] == pytest.approx(tau[-200], rel=1e-6)  # a plateau, not a transient


@pytest.mark.parametrize("plasticity, limit", [("fe", 2.0), ("fe_bdf2", 4.0)])
def test_relaxation_stability_limit(plasticity, limit):
    """fe and fe_bdf2 relax explicitly, so they are only conditionally stable (the thesis
    suspects fe_bdf2, §6.1.4). Linearising f' = (f^-T - f)/(2 Wi) at f = I: fe gives
    e' = (1 - r) e, stable for r = dt/Wi < 2; fe_bdf2 gives (3 + r) e'' = (4 - 2r) e' + (r - 1) e,
    whose root crosses -1 at r = 4. Relaxing from the W = 1 steady-shear conformation for 3000
    steps: 2 % below the limit b reaches I to round-off, 2 % above it the period-2 mode has
    grown into a large oscillation that never settles (nonlinear run = linear theory). ob_spd
    has no limit (test_b_stays_spd_at_large_steps)."""
    def deviation(ratio):
        """max |b - I| over the last 100 steps."""
        L, A0, _, _ = flow("relaxation", 2, 1.0)
        res = drive(oldroyd_b(2, plasticity, viscosity=0.0), lambda t: L, ratio * WI, 3000,
                    state={"b": A0, "Fe": np.linalg.cholesky(A0)}, record=("b",))
        return np.abs(res.history["b"][-100:, 0] - np.eye(2)).max()
    initial = 2.0  # |A0 - I| max = 2 W^2
    assert deviation(0.98 * limit) < 1e-12 * initial
    assert deviation(1.02 * limit) > 5.0 * initial


@pytest.mark.parametrize("h", (0.5, 1.0, 2.0))
@pytest.mark.parametrize("rate", (0.1, 1.0))
def test_herschel_bulkley_implicit_flow_curve_at_large_steps(rate, h):
    """The implicit return (flow_update = "implicit", 2D) reaches the flow curve
    tau_y + K gdot^h at steps far beyond the explicit update's: dt gdot = 0.01 (the explicit
    update has lost the flow curve there at rate 0.1: -69 %) and 0.1. Its remaining error is
    the finite shear per step k = dt gdot: the return keeps the principal axes of the trial
    A b A^T, tilted from 45 degrees by the step's rotation, so tau_xy = |dev tau| sin 2 theta
    with sin 2 theta ~ 2 / sqrt(4 + k^2) (measured -1.6e-3 ... -2.5e-3 at k = 0.1, -1.2 % ...
    -1.6 % at k = 0.3, -11 % ... -13 % at k = 1: second order in k). 0.5 % (issue 9)."""
    mat = make_material(Spec("herschel_bulkley", {
        "mu": MU, "lambda": LAM, "yield_strain": 0.01, "flow_consistency": 0.01,
        "flow_index": h, "flow_update": "implicit"}), 2)
    L = np.zeros((2, 2))
    L[0, 1] = rate
    expected = hb_flow_curve(0.01, 0.01, h, rate)
    for k, steps in ((0.01, 3000), (0.1, 300)):
        # Elastic strain ~1e-2 is loaded in ~1e-2/k steps; backward Euler reaches the
        # steady state without overshoot, so 30 / k steps are ample.
        tau = drive(mat, lambda t: L, k / rate, steps).sigma()[:, 0, 0, 1]
        assert abs(tau[-1] - tau[-10]) <= 1e-9 * expected  # steady
        assert tau[-1] == pytest.approx(expected, rel=5e-3), (k, tau[-1] / expected - 1)


def test_von_mises_implicit_plateau():
    """The implicit (rate-independent, eta = 0) return: the shear plateau mu sigma_Y / sqrt2
    within 0.5 % (issue 9) at a step 100x the explicit test's, dt gdot = 0.01 (the tilt of
    the previous test is 1e-5 there)."""
    sigma_y = 0.01
    mat = make_material(Spec("von_mises", {"mu": MU, "lambda": LAM, "yield_strain": sigma_y,
                                           "flow_update": "implicit"}), 2)
    L = np.zeros((2, 2))
    L[0, 1] = 1.0
    tau = drive(mat, lambda t: L, 1e-2, 100).sigma()[:, 0, 0, 1]  # shear strain 1
    assert tau[-1] == pytest.approx(MU * sigma_y / math.sqrt(2.0), rel=5e-3)
    assert tau[-1] == pytest.approx(tau[-20], rel=1e-9)


@pytest.mark.parametrize("plasticity", PLASTICITIES)
@pytest.mark.parametrize("dim", [2, 3])
def test_newtonian_fluid_shears_forever(dim, plasticity):
    """mu = 0 (a Newtonian fluid): steady shear to a strain of 2e4 keeps the exact stress
    sigma_xy = mu_N gdot and J = 1 (round-off: 1e-12). The conformation, which enters nothing
    at mu = 0, is not advanced: advanced, tr b grows as the strain squared (4e8 here), and in
    the Newtonian channel det b_hat was lost to round-off at t = 25.7, which stopped the run
    as inadmissible."""
    mat = make_material(Spec("oldroyd_b", {"mu": 0.0, "lambda": LAM, "viscosity": MU_N,
                                           "relaxation_time": math.inf,
                                           "plasticity": plasticity}), dim)
    rate = 100.0
    L = np.zeros((dim, dim))
    L[0, 1] = rate
    res = drive(mat, lambda t: L, 1.0, 200)        # shear strain 2e4
    sigma = res.sigma()[-1, 0]
    assert sigma[0, 1] == pytest.approx(MU_N * rate, rel=1e-12)
    assert abs(res.J[-1, 0] - 1.0) < 1e-12
    np.testing.assert_array_equal(res.fields["b"][0], np.eye(dim))


@pytest.mark.parametrize("h", (0.5, 2.0))
def test_herschel_bulkley_flow_curve_method_is_the_steady_stress(h):
    """HerschelBulkley.flow_curve(gdot), the documented tau_y + K gdot^h, is the steady stress
    the driven material point reaches (2D, the run of the steady flow-curve test)."""
    mat = make_material(Spec("herschel_bulkley", {
        "mu": MU, "lambda": LAM, "yield_strain": 0.01, "flow_consistency": 0.01,
        "flow_index": h}), 2)
    L = np.zeros((2, 2))
    L[0, 1] = 1.0
    res = drive(mat, lambda t: L, 1e-4, 5000)
    # 0.5 % as the flow-curve test (measured 0.003 % to 0.02 % there); a wrong exponent of 2
    # in K is a factor 2^(1/2).
    assert mat.flow_curve(1.0) == pytest.approx(res.sigma()[-1, 0, 0, 1], rel=5e-3)


def test_von_mises_shear_yield_stress_method_is_the_plateau():
    """VonMises.shear_yield_stress() is the simple-shear plateau the driven point reaches."""
    mat = make_material(Spec("von_mises", {"mu": MU, "lambda": LAM, "yield_strain": 0.01}), 2)
    L = np.zeros((2, 2))
    L[0, 1] = 1.0
    res = drive(mat, lambda t: L, 1e-4, 2000)
    # 0.5 % as the plateau test (measured 3e-5 there).
    assert mat.shear_yield_stress() == pytest.approx(res.sigma()[-1, 0, 0, 1], rel=5e-3)

"""Semi-implicit hooks of every model (HELPERS item 3, issue 9 "Derivatives on random states"):
the gradient is the derivative of the energy and the Hessian-vector product the derivative of
the gradient (Taylor remainders), the Hessian is symmetric, at L = 0 the gradient is dt V0 tau
(the eq. 5.9 force), b stays SPD and det b_E = J^2.

e(L) = sum_p e_p(L_p) with the state at t^n fixed; G_p = de_p/dL_p, dG_p = D^2 e_p[dL_p].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from hpcmpm.kernels.tangent import pack, packed_size
from hpcmpm.materials import make_material
from hpcmpm.materials.driver import initial_fields

DIMS = (2, 3)
N = 6  # particles per random state
DT = 0.3
# Every model and every plastic update, with parameters that make each term matter: mu_N > 0,
# dt/Wi = 0.6, HB above yield (alpha > 0) with h != 1.
ELASTIC = {"E": 10.0, "nu": 0.3}
VISCO = {"mu": 3.0, "lambda": 5.0, "viscosity": 0.7}
CASES = {
    "linear_elastic": ("linear_elastic", ELASTIC),
    "fixed_corotated": ("fixed_corotated", ELASTIC),
    "neo_hookean": ("neo_hookean", ELASTIC),
    "stable_neo_hookean": ("stable_neo_hookean", ELASTIC),
    "snow": ("snow", {**ELASTIC, "theta_c": 0.025, "theta_s": 0.0075, "xi": 10.0}),
    "weakly_compressible": ("weakly_compressible", {"E": 10.0}),
    **{f"oldroyd_b/{p}": ("oldroyd_b", {**VISCO, "relaxation_time": 0.5, "plasticity": p})
       for p in ("ob_spd", "ob_explicit", "fe", "fe_bdf2")},
    "herschel_bulkley": ("herschel_bulkley", {**VISCO, "yield_strain": 0.05,
                                              "flow_consistency": 0.2, "flow_index": 0.6}),
    "von_mises": ("von_mises", {**VISCO, "yield_strain": 0.05}),
}
# Energies quadratic in L: the gradient is linear, so its Taylor remainder is round-off only.
QUADRATIC = {"linear_elastic"}


@dataclass
class Spec:
    type: str
    params: dict
    density: float = 1.0
    name: str = "m"


def material(case: str, dim: int, **extra):
    type_name, params = CASES[case]
    return make_material(Spec(type_name, {**params, **extra}), dim)


def random_F(rng, d: int, lo: float = 0.7, hi: float = 1.4) -> np.ndarray:
    def rotation():
        Q, R = np.linalg.qr(rng.normal(size=(d, d)))
        Q = Q * np.sign(np.diag(R))
        if np.linalg.det(Q) < 0:
            Q[:, 0] *= -1
        return Q
    return rotation() @ np.diag(rng.uniform(lo, hi, d)) @ rotation()


def random_state(mat, rng, n: int = N) -> dict:
    """Fields of n particles in a random admissible state at t^n."""
    d = mat.dim
    f = initial_fields(mat, n)
    f["vol0"][:] = rng.uniform(0.5, 1.5, n)
    Fs = np.stack([random_F(rng, d) for _ in range(n)])
    if "F" in f:
        f["F"][:] = Fs
    if "b" in f:
        f["b"][:] = Fs @ Fs.transpose(0, 2, 1)
        f["J"][:] = np.linalg.det(Fs) * rng.uniform(0.9, 1.1, n)  # b_OB need not have det J^2
        if mat.name != "oldroyd_b":  # HB, von Mises store det b = J^2
            f["J"][:] = np.linalg.det(Fs)
    elif "J" in f:
        f["J"][:] = rng.uniform(0.7, 1.3, n)
    if "Fe" in f:
        f["Fe"][:] = Fs
        f["b"][:] = Fs @ Fs.transpose(0, 2, 1)
    if "Fe_prev" in f:
        f["Fe_prev"][:] = np.stack([random_F(rng, d, 0.8, 1.2) for _ in range(n)]) @ Fs
    if "Jp" in f:
        f["Jp"][:] = rng.uniform(0.8, 1.2, n)
    return f


def hooks(mat, f):
    def energy(L):
        return mat.implicit_energy(f, L, DT)

    def gradient(L):
        G = np.full_like(L, np.nan)
        mat.implicit_gradient(f, L, DT, G)
        return G

    def hessian(L, dL):
        dG = np.full_like(L, np.nan)
        mat.implicit_hessian(f, L, DT, dL, dG)
        return dG
    return energy, gradient, hessian


def seed(case: str, dim: int) -> list[int]:
    return [sorted(CASES).index(case), dim]


def slope(hs, remainders) -> float:
    return float(np.polyfit(np.log(hs), np.log(remainders), 1)[0])


HS = 1e-2 * 0.5 ** np.arange(6)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_taylor_remainders(case, dim):
    """|e(L + h D) - e(L) - h G:D| and |G(L + h D) - G(L) - h H[D]| are O(h^2)."""
    rng = np.random.default_rng(seed(case, dim))
    mat = material(case, dim)
    for _ in range(3):
        f = random_state(mat, rng)
        energy, gradient, hessian = hooks(mat, f)
        L = 0.4 * rng.normal(size=(N, dim, dim))
        D = rng.normal(size=L.shape)
        D /= np.linalg.norm(D)
        e0, G0, HD = energy(L), gradient(L), hessian(L, D)
        assert math.isfinite(e0) and np.all(np.isfinite(G0)) and np.all(np.isfinite(HD))
        r_energy = [abs(energy(L + h * D) - e0 - h * np.sum(G0 * D)) for h in HS]
        r_gradient = [np.linalg.norm(gradient(L + h * D) - G0 - h * HD) for h in HS]
        # e ~ 1-10 and |G| ~ 1: round-off in the remainders is ~1e-14, far below the smallest
        # truncation remainder (~1e-7 at h = 3e-4), so the slope is the order, 2. A wrong
        # gradient or Hessian leaves an O(h) remainder (slope 1). Issue 9: 2 +- 0.1.
        assert abs(slope(HS, r_energy) - 2.0) <= 0.1, (case, r_energy)
        if case in QUADRATIC:
            # Exact to round-off: G is linear in L.
            assert max(r_gradient) <= 1e-12 * np.linalg.norm(G0), (case, r_gradient)
        else:
            assert abs(slope(HS, r_gradient) - 2.0) <= 0.1, (case, r_gradient)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_hessian_is_symmetric(case, dim):
    rng = np.random.default_rng(seed(case, dim))
    mat = material(case, dim)
    f = random_state(mat, rng)
    _, _, hessian = hooks(mat, f)
    L = 0.4 * rng.normal(size=(N, dim, dim))
    for _ in range(3):
        U, W = rng.normal(size=L.shape), rng.normal(size=L.shape)
        uHw, wHu = np.sum(U * hessian(L, W)), np.sum(W * hessian(L, U))
        scale = np.linalg.norm(U) * np.linalg.norm(hessian(L, W))
        # The same products summed in a different order: relative round-off of a few ulps
        # times the ~30 terms per entry; 1e-12 (issue 9).
        assert abs(uHw - wHu) <= 1e-12 * scale, (case, uHw, wHu)


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_hessian_product_is_linear_in_the_direction(case, dim):
    """D^2 e_p[a U + b W] = a D^2 e_p[U] + b D^2 e_p[W]: the semi-implicit solve builds each
    particle's tangent T_p from d^2 products with unit directions once per linearization and
    applies T_p : dL in CG (solvers/semi_implicit.py `_tangent`), which is only the material's
    product if that is linear in dL (no branch or return map on dL itself). Relative 1e-12:
    the same terms summed in another grouping."""
    rng = np.random.default_rng(seed(case, dim))
    mat = material(case, dim)
    f = random_state(mat, rng)
    _, _, hessian = hooks(mat, f)
    L = 0.4 * rng.normal(size=(N, dim, dim))
    U, W = rng.normal(size=L.shape), rng.normal(size=L.shape)
    a, b = 1.7, -0.6
    both = hessian(L, a * U + b * W)
    apart = a * hessian(L, U) + b * hessian(L, W)
    # The tangent from unit directions reproduces the product for a random direction.
    T = np.stack([hessian(L, np.broadcast_to(np.eye(dim * dim)[k].reshape(dim, dim),
                                             L.shape).copy()) for k in range(dim * dim)],
                 axis=-1).reshape(N, dim * dim, dim * dim)
    via_tangent = np.einsum("pkl,pl->pk", T, U.reshape(N, -1)).reshape(L.shape)
    scale = np.abs(both).max()
    assert scale > 0.0
    assert np.abs(both - apart).max() <= 1e-12 * scale, case
    assert np.abs(via_tangent - hessian(L, U)).max() <= 1e-12 * np.abs(hessian(L, U)).max(), case


def rest_cases():
    """Every case with Wi = inf (no relaxation at L = 0); fe_bdf2 separately below."""
    out = []
    for case in sorted(CASES):
        if case == "oldroyd_b/fe_bdf2":
            continue
        extra = {"relaxation_time": math.inf} if case.startswith("oldroyd_b") else {}
        out.append((case, extra))
    return out


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case, extra", rest_cases())
def test_gradient_at_rest_is_the_kirchhoff_force(case, extra, dim):
    """At L = 0 (v_hat = 0) with Wi = inf, de_p/dL_p = dt V0_p tau_p^n: the implicit grid
    force f_i = -sum_p G_p grad w_ip / dt = -sum_p V0_p tau_p grad w_ip is the explicit eq. 5.9
    force. For HB this needs the state below yield (alpha = 0); the viscous term vanishes at
    L = 0."""
    rng = np.random.default_rng(seed(case, dim))
    if case == "herschel_bulkley":
        extra = {"yield_strain": 1e3}  # below yield
    if case == "snow":
        extra = {"theta_c": 0.9, "theta_s": 10.0}  # a clamp the random F do not reach
    mat = material(case, dim, **extra)
    f = random_state(mat, rng)
    _, gradient, _ = hooks(mat, f)
    G = gradient(np.zeros((N, dim, dim)))
    f["L"][:] = 0.0
    mat.update_stress(f, DT)
    expected = DT * f["vol0"][:, None, None] * f["tau"]
    # Both are O(10) sums of a few products of O(1) numbers: 1e-12 relative (issue 9).
    assert np.abs(G - expected).max() <= 1e-12 * np.abs(expected).max(), case


@pytest.mark.parametrize("dim", DIMS)
def test_fe_bdf2_force_at_rest(dim):
    """fe_bdf2 (Wi = inf): with no history (first step) the gradient at rest is dt V0 tau
    like fe; with F_E^{n-1} = F_E^n (a body at rest) BDF2's L enters b_hat with the factor
    2 dt / 3, so the potential's force is tau_vol + (2/3) tau_dev (deviatoric part of mu b_E):
    the semi-implicit force of fe_bdf2 is not the eq. 5.9 force (see oldroyd_b.py)."""
    rng = np.random.default_rng(dim)
    mat = material("oldroyd_b/fe_bdf2", dim, relaxation_time=math.inf)
    f = random_state(mat, rng)
    f["Fe_prev"][:] = 0.0  # no history
    f["J"][:] = np.linalg.det(f["Fe"])
    _, gradient, _ = hooks(mat, f)
    zero = np.zeros((N, dim, dim))
    f["L"][:] = 0.0
    mat.update_stress(f, DT)
    tau = DT * f["vol0"][:, None, None] * f["tau"]
    assert np.abs(gradient(zero) - tau).max() <= 1e-12 * np.abs(tau).max()
    f["Fe_prev"][:] = f["Fe"]
    bE = mat.elastic_strain(f)
    dev = DT * f["vol0"][:, None, None] * mat.mu * (
        bE - np.trace(bE, axis1=1, axis2=2)[:, None, None] / dim * np.eye(dim))
    assert np.abs(gradient(zero) - (tau - dev / 3.0)).max() <= 1e-12 * np.abs(tau).max()


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case", ["oldroyd_b/ob_spd", "herschel_bulkley"])
def test_b_stays_spd_at_large_steps(case, dim):
    """ob_spd (§4.6.1) and HB (§4.6.2) keep b SPD for any L with det(I + dt L) > 0, here at
    dt/Wi up to 100 (HB: dt up to 100 in units of eta) and dt |L| up to ~10."""
    rng = np.random.default_rng(seed(case, dim))
    for ratio in (0.1, 1.0, 10.0, 100.0):
        mat = material(case, dim, **({"relaxation_time": 1.0} if "oldroyd" in case else {}))
        f = random_state(mat, rng, 200)
        L = rng.normal(size=(200, dim, dim)) * rng.uniform(0.1, 10.0, (200, 1, 1)) / ratio
        keep = np.linalg.det(np.eye(dim) + ratio * L) > 0  # J > 0: inversions are rejected
        f = {k: v[keep] for k, v in f.items()}
        f["L"][:] = L[keep]
        mat.update_state(f, ratio)
        assert not mat.failures
        eig = np.linalg.eigvalsh(f["b"])
        # SPD by construction: eigenvalues positive, not merely above round-off.
        assert np.all(eig > 0.0), (case, ratio, eig.min())
        assert np.array_equal(f["b"], f["b"].transpose(0, 2, 1))  # symmetric to the bit


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("case", ["oldroyd_b/ob_spd", "oldroyd_b/fe", "oldroyd_b/fe_bdf2",
                                  "oldroyd_b/ob_explicit", "herschel_bulkley", "von_mises"])
def test_elastic_strain_determinant_is_J_squared(case, dim):
    """b_E = (J^2/det b)^(1/d) b after random steps: det b_E = J^2 (000 eq. 5.5: the plastic
    flow is isochoric)."""
    rng = np.random.default_rng(seed(case, dim))
    mat = material(case, dim)
    f = random_state(mat, rng, 50)
    for _ in range(5):
        f["L"][:] = 0.3 * rng.normal(size=(50, dim, dim))
        mat.update_state(f, 0.2)
    assert not mat.failures
    bE = mat.elastic_strain(f)
    # One d-th root and a determinant of O(1) entries: a few ulps; 1e-12 (issue 9).
    assert np.allclose(np.linalg.det(bE), f["J"] ** 2, rtol=1e-12, atol=0)
    if case in ("herschel_bulkley", "von_mises"):  # these store the rescaled b itself
        assert np.allclose(np.linalg.det(f["b"]), f["J"] ** 2, rtol=1e-12, atol=0)


@pytest.mark.parametrize("dim", DIMS)
def test_inadmissible_states(dim):
    """E = +inf when det F_hat or det b_hat <= 0 (the Newton line search rejects the step);
    update_state writes NaN into J and a one-line failure naming the particle id."""
    rng = np.random.default_rng(dim)
    L = np.zeros((N, dim, dim))
    L[2] = np.diag([-5.0] + [1.0] * (dim - 1))  # det(I + dt L) < 0: an inverted particle
    for case in ("oldroyd_b/ob_spd", "herschel_bulkley", "neo_hookean", "fixed_corotated",
                 "weakly_compressible"):
        mat = material(case, dim)
        f = random_state(mat, rng)
        assert mat.implicit_energy(f, L, DT) == math.inf, case
    mat = material("oldroyd_b/ob_spd", dim)
    f = random_state(mat, rng)
    f["id"][:] = np.arange(100, 100 + N)
    f["L"][:] = L
    mat.update_state(f, DT)
    assert math.isnan(f["J"][2]) and np.all(np.isfinite(np.delete(f["J"], 2)))
    (message,) = mat.failures
    assert "particle id 102" in message and "J = " in message


TANGENT_CASES = [(case, dim, {}) for case in sorted(CASES) for dim in DIMS] + [
    # The implicit isochoric return (2D only): its own Hessian product per direction.
    ("herschel_bulkley", 2, {"flow_update": "implicit"}),
    ("von_mises", 2, {"flow_update": "implicit"})]


@pytest.mark.parametrize("case, dim, extra", TANGENT_CASES,
                         ids=[f"{c}-{d}d{'-implicit' if e else ''}" for c, d, e in TANGENT_CASES])
def test_implicit_tangent_equals_the_unit_direction_products(case, dim, extra):
    """`implicit_tangent` (one pass over the particles for the b_E models, the base class's
    d^2 products otherwise) equals the tangent stacked from `implicit_hessian` with each unit
    direction, the way the solver built it before: 1e-13 relative (the same arithmetic; the
    one-pass kernel shares the per-particle parts between the directions). It is stored as
    its upper triangle (kernels/tangent.py), which the symmetry of the stacked one allows."""
    rng = np.random.default_rng(seed(case, dim))
    mat = material(case, dim, **extra)
    f = random_state(mat, rng)
    _, _, hessian = hooks(mat, f)
    L = 0.4 * rng.normal(size=(N, dim, dim))
    k2 = dim * dim
    stacked = np.stack([hessian(L, np.broadcast_to(np.eye(k2)[k].reshape(dim, dim),
                                                   L.shape).copy()) for k in range(k2)],
                       axis=-1).reshape(N, k2, k2)
    T = np.full((N, packed_size(k2)), np.nan)
    mat.implicit_tangent(f, L, DT, np.empty_like(L), np.empty_like(L), T)
    scale = np.abs(stacked).max()
    assert scale > 0.0
    # The tangent is stored as its upper triangle (kernels/tangent.py), every entry written.
    assert np.abs(T - pack(stacked)).max() <= 1e-13 * scale, \
        (case, np.abs(T - pack(stacked)).max() / scale)
    # What keeping the upper triangle rests on: a Hessian is symmetric. The stacked products
    # are, to 2.2e-16 of the largest entry in every case here (the mixed derivatives summed
    # in two orders); 1e-14 leaves a few ulps' room, and a model whose tangent lost its
    # symmetry (a wrong factor in one of two mixed terms) would be off by O(1).
    asym = np.abs(stacked - stacked.transpose(0, 2, 1)).max() / scale
    assert asym <= 1e-14, (case, asym)

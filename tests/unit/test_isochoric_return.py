"""The implicit viscoplastic return of Herschel-Bulkley and von Mises (flow_update =
"implicit", hpcmpm/materials/isochoric_return.py): its incremental potential's derivatives
(Taylor remainders, symmetry), force = stress of the returned state, the HB law at the end of
the step, det b = J^2, SPD at large steps, and how "auto" resolves.

The random states are beyond yield for every particle (`state_and_L`), so the return is active
and the derivative tests do not straddle the yield kink.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hpcmpm.errors import SceneError
from hpcmpm.materials.left_cauchy_green import HB, HB_IMPLICIT, VM

from test_implicit_derivatives import DT, HS, N, hooks, material, random_state, slope

# HB with shear thinning, Bingham and thickening flow indices, and von Mises (eta = 0).
CASES = {
    "hb_h0.6": ("herschel_bulkley", {"flow_update": "implicit"}),
    "hb_h1": ("herschel_bulkley", {"flow_update": "implicit", "flow_index": 1.0}),
    "hb_h1.7": ("herschel_bulkley", {"flow_update": "implicit", "flow_index": 1.7}),
    "von_mises": ("von_mises", {"flow_update": "implicit"}),
}


def make(case: str):
    kind, extra = CASES[case]
    return material(kind, 2, **extra)


def seed(case: str) -> int:
    return 100 + sorted(CASES).index(case)


def log_gap(b: np.ndarray) -> np.ndarray:
    """delta = e_1 - e_2, the difference of the principal log stretches of each 2x2 b."""
    eig = np.linalg.eigvalsh(b)
    return 0.5 * np.log(eig[:, 1] / eig[:, 0])


def trial(f, L, dt):
    """b_tr = A b^n A^T and J, computed with numpy (independent of the kernels)."""
    A = np.eye(2) + dt * L
    return A @ f["b"] @ A.transpose(0, 2, 1), f["J"] * np.linalg.det(A)


def state_and_L(mat, rng, n: int = N):
    """A random state and L whose trial is beyond yield for every particle (|dev b_tr| >
    2 sigma_Y; a particle's L is redrawn until it is), so the return, not the elastic branch,
    is what the tests see, away from the yield kink."""
    f = random_state(mat, rng, n)
    L = 0.4 * rng.normal(size=(n, 2, 2))
    for _ in range(100):
        btr, _ = trial(f, L, DT)
        dev = btr - np.trace(btr, axis1=1, axis2=2)[:, None, None] / 2 * np.eye(2)
        low = np.linalg.norm(dev, axis=(1, 2)) <= 2 * mat.sigma_y
        if not low.any():
            return f, L
        L[low] = 0.4 * rng.normal(size=(int(low.sum()), 2, 2))
    raise AssertionError("no flowing state drawn")


@pytest.mark.parametrize("case", sorted(CASES))
def test_taylor_remainders(case):
    """|e(L + hD) - e(L) - h G:D| and |G(L + hD) - G(L) - h H[D]| are O(h^2) (issue 9:
    slope 2 +- 0.1): G is the exact derivative of the potential with the return inside, H the
    consistent tangent (implicit function theorem on the scalar return)."""
    rng = np.random.default_rng(seed(case))
    mat = make(case)
    for _ in range(3):
        f, L = state_and_L(mat, rng)
        energy, gradient, hessian = hooks(mat, f)
        D = rng.normal(size=L.shape)
        D /= np.linalg.norm(D)
        e0, G0, HD = energy(L), gradient(L), hessian(L, D)
        r_energy = [abs(energy(L + h * D) - e0 - h * np.sum(G0 * D)) for h in HS]
        r_gradient = [np.linalg.norm(gradient(L + h * D) - G0 - h * HD) for h in HS]
        # Remainders ~1e-8 at the smallest h against round-off ~1e-14 (the return is solved
        # to a relative 1e-15): the fitted slope is the order.
        assert abs(slope(HS, r_energy) - 2.0) <= 0.1, r_energy
        assert abs(slope(HS, r_gradient) - 2.0) <= 0.1, r_gradient


@pytest.mark.parametrize("case", sorted(CASES))
def test_hessian_is_symmetric(case):
    """u.Hw = w.Hu to 1e-12 (issue 9): e is a potential (the plastic decrement is a
    minimiser), so its consistent tangent is symmetric."""
    rng = np.random.default_rng(seed(case))
    mat = make(case)
    f, L = state_and_L(mat, rng)
    _, _, hessian = hooks(mat, f)
    for _ in range(3):
        U, W = rng.normal(size=L.shape), rng.normal(size=L.shape)
        uHw, wHu = np.sum(U * hessian(L, W)), np.sum(W * hessian(L, U))
        scale = np.linalg.norm(U) * np.linalg.norm(hessian(L, W))
        assert abs(uHw - wHu) <= 1e-12 * scale, (uHw, wHu)


@pytest.mark.parametrize("case", sorted(CASES))
def test_force_is_the_stress_of_the_returned_state(case):
    """de_p/dL_p = dt V0 tau^{n+1} (I + dt L)^-T with tau^{n+1} the stress of the state
    update_state stores from the same L: what the solve balances is what the step keeps (the
    issue's explicit update gives ~tau/(1 + alpha) here). 1e-12 relative: the same scalar
    return evaluated twice, a few products of O(1) numbers."""
    rng = np.random.default_rng(seed(case))
    mat = make(case)
    f, L = state_and_L(mat, rng)
    _, gradient, _ = hooks(mat, f)
    G = gradient(L)
    f["L"][:] = L
    mat.update_state(f, DT)
    assert not mat.failures
    mat.update_stress({**f, "L": np.zeros_like(L)}, DT)  # elastic part only
    AiT = np.linalg.inv(np.eye(2) + DT * L).transpose(0, 2, 1)
    viscous = 2 * mat.viscosity * (f["J"] / np.linalg.det(np.eye(2) + DT * L))[:, None, None] \
        * 0.5 * (L + L.transpose(0, 2, 1))
    expected = DT * f["vol0"][:, None, None] * (f["tau"] @ AiT + viscous)
    assert np.abs(G - expected).max() <= 1e-12 * np.abs(expected).max()


@pytest.mark.parametrize("case", ["hb_h0.6", "hb_h1", "hb_h1.7"])
def test_end_of_step_flow_rule(case):
    """The returned state satisfies the HB law at t^{n+1} (backward Euler): with
    Delta = delta_tr - delta the removed log-strain gap (numpy eigenvalues, independent of the
    kernel's invariants), gdot = Delta / (sqrt2 dt) and |dev b^{n+1}| = sigma_Y + eta gdot^h;
    principal directions kept; det b = J^2. 1e-10: eigenvalue round-off of O(1) matrices
    relative to the O(0.1-1) strains."""
    rng = np.random.default_rng(seed(case))
    mat = make(case)
    h = 1.0 / mat.inv_h
    f, L = state_and_L(mat, rng)
    btr, J = trial(f, L, DT)
    f["L"][:] = L
    mat.update_state(f, DT)
    b = f["b"]
    assert np.allclose(np.linalg.det(b), J ** 2, rtol=1e-12, atol=0)
    gdot = (log_gap(btr) - log_gap(b)) / (math.sqrt(2) * DT)
    assert np.all(gdot > 0)
    dev = b - np.trace(b, axis1=1, axis2=2)[:, None, None] / 2 * np.eye(2)
    norm = np.linalg.norm(dev, axis=(1, 2))
    assert np.allclose(norm, mat.sigma_y + mat.eta * gdot ** h, rtol=1e-10, atol=0)
    commutator = b @ btr - btr @ b
    assert np.abs(commutator).max() <= 1e-12 * np.abs(btr).max() ** 2


def test_hessian_decrements_follow_the_linearisation_point():
    """The Hessian reuses the return's decrements while (state, L, dt) stay the same
    (`_decrements`): products at a second L, after an in-place change of L, of b and of dt,
    each equal a fresh material's, bitwise (the same kernels on the same inputs); a stale
    decrement would differ by O(1) relative (the states are beyond yield)."""
    rng = np.random.default_rng(11)
    mat = make("hb_h0.6")
    f, L = state_and_L(mat, rng)
    D = rng.normal(size=L.shape)

    def product(m, fields, L, dt):
        dG = np.full_like(L, np.nan)
        m.implicit_hessian(fields, L, dt, D, dG)
        return dG

    def fresh(fields, L, dt):
        return product(make("hb_h0.6"), {k: v.copy() for k, v in fields.items()}, L, dt)

    first = product(mat, f, L, DT)
    assert np.array_equal(product(mat, f, L, DT), first)  # reused
    _, L2 = state_and_L(mat, rng)
    L[:] = L2  # in place: the key holds a copy
    changed = product(mat, f, L, DT)
    assert np.array_equal(changed, fresh(f, L, DT))
    assert np.abs(changed - first).max() > 1e-3 * np.abs(first).max()
    f["b"][0] *= 1.01
    assert np.array_equal(product(mat, f, L, DT), fresh(f, L, DT))
    assert np.array_equal(product(mat, f, L, 0.5 * DT), fresh(f, L, 0.5 * DT))


def test_von_mises_returns_to_the_yield_surface():
    """eta = 0: |dev b^{n+1}| = sigma_Y exactly beyond yield."""
    rng = np.random.default_rng(7)
    mat = make("von_mises")
    f, L = state_and_L(mat, rng)
    f["L"][:] = L
    mat.update_state(f, DT)
    b = f["b"]
    dev = b - np.trace(b, axis1=1, axis2=2)[:, None, None] / 2 * np.eye(2)
    assert np.allclose(np.linalg.norm(dev, axis=(1, 2)), mat.sigma_y, rtol=1e-12, atol=0)


@pytest.mark.parametrize("case", ["hb_h0.6", "von_mises"])
def test_b_stays_spd_at_large_steps(case):
    """b^{n+1} = J [cosh(delta) I + sinh(delta)/s_tr X] has eigenvalues J e^(+-delta) > 0 for
    any L with det(I + dt L) > 0, here with dt |L| up to ~100."""
    rng = np.random.default_rng(seed(case))
    mat = make(case)
    for dt in (0.1, 1.0, 10.0, 100.0):
        f = random_state(mat, rng, 200)
        L = rng.normal(size=(200, 2, 2)) * rng.uniform(0.1, 10.0, (200, 1, 1))
        keep = np.linalg.det(np.eye(2) + dt * L) > 0
        f = {k: v[keep] for k, v in f.items()}
        f["L"][:] = L[keep]
        mat.update_state(f, dt)
        assert not mat.failures
        assert np.all(np.linalg.eigvalsh(f["b"]) > 0.0)


def test_flow_update_choice():
    """"auto" is implicit under the semi-implicit integrator in 2D and explicit otherwise,
    and its note (run log, `hpcmpm validate`) names the choice; "implicit" in 3D is refused
    with one line naming the key."""
    for kind, explicit in (("herschel_bulkley", HB), ("von_mises", VM)):
        mat = material(kind, 2)
        assert mat.mode == explicit  # before configure: explicit
        mat.configure(SimpleNamespace(integrator="semi_implicit", dx=0.1, dt=0.01))
        assert mat.mode == HB_IMPLICIT
        (note,) = mat.notes()
        assert 'flow_update = "auto" runs implicit' in note
        mat = material(kind, 2)
        mat.configure(SimpleNamespace(integrator="explicit", dx=0.1, dt=0.01))
        assert mat.mode == explicit
        (note,) = mat.notes()
        assert 'flow_update = "auto" runs explicit' in note
        mat = material(kind, 3)
        mat.configure(SimpleNamespace(integrator="semi_implicit", dx=0.1, dt=0.01))
        assert mat.mode == explicit
        assert 'runs explicit' in mat.notes()[0]
        assert material(kind, 2, flow_update="explicit").notes() == []  # chosen: no note
        with pytest.raises(SceneError, match="flow_update: 'implicit' is built for 2D only"):
            material(kind, 3, flow_update="implicit")


@pytest.mark.parametrize("case", ["hb_h0.6", "von_mises"])
def test_returns_solved_once_per_point_give_the_same_bits(case, monkeypatch):
    """A Newton iteration evaluates the energy, the gradient, the tangent and (after G2P) the
    state update at one L; the return's decrements are solved once there and reused
    (`_known_decrements`). Every hook must give the bits of fresh materials that solve their
    own, and a different L, state or dt must not reuse them."""
    from hpcmpm.materials import left_cauchy_green as lcg

    rng = np.random.default_rng(seed(case) + 50)
    f, L = state_and_L(make(case), rng)

    def results(L, state, dt, materials):
        """Energy, gradient, tangent and updated (b, J), each hook from materials[k]."""
        e = materials[0].implicit_energy(state, L, dt)
        G = np.empty_like(L)
        materials[1].implicit_gradient(state, L, dt, G)
        T = np.empty((len(L), 10))  # packed (kernels/tangent.py)
        materials[2].implicit_tangent(state, L, dt, None, None, T)
        new = {k: v.copy() for k, v in state.items()}
        new["L"] = L.copy()
        materials[3].update_state(new, dt)
        return e, G, T, new["b"], new["J"]

    def fresh(*args):
        return results(*args, [make(case) for _ in range(4)])

    mat = make(case)
    for a, b in zip(results(L, f, DT, [mat] * 4), fresh(L, f, DT)):
        assert np.array_equal(a, b)
    # The energy solved the returns at L; the tangent finds them without solving.
    mat.implicit_energy(f, L, DT)
    assert mat._known_decrements(f, L, DT) is not None
    calls = []
    original = lcg.return_decrements
    monkeypatch.setattr(lcg, "return_decrements",
                        lambda *args: calls.append(1) or original(*args))
    mat.implicit_tangent(f, L, DT, None, None, np.empty((len(L), 10)))
    assert calls == []
    # Another L (one ulp in one entry), another state, another dt: solved anew, same bits.
    L2 = L.copy()
    L2[3, 0, 1] = np.nextafter(L2[3, 0, 1], np.inf)
    f2 = {k: v.copy() for k, v in f.items()}
    f2["J"][5] *= 1.0 + 1e-6
    for Lx, fx, dtx in ((L2, f, DT), (L, f2, DT), (L, f, DT * 1.5)):
        mat.implicit_energy(f, L, DT)              # the returns at (L, f, DT) remembered
        assert mat._known_decrements(fx, Lx, dtx) is None
        for a, b in zip(results(Lx, fx, dtx, [mat] * 4), fresh(Lx, fx, dtx)):
            assert np.array_equal(a, b)


def test_plastic_decrement_is_the_root_of_the_flow_law():
    """The return's scalar Newton (bracketed, on the inverted law for h > 1) against a plain
    bisection of g(Delta) = J sinh(delta_tr - Delta) - D'(Delta) written here, over flow
    indices from strong thinning to h = 10 and yield stresses, consistencies and steps over
    several decades. Both stop at a bracket of 1e-15 delta_tr, so they agree to a few of
    those (the bisection's own width and the round-off of g near its root)."""
    from hpcmpm.materials.isochoric_return import plastic_decrement

    def reference(J, delta_tr, dt, sigma_y, h, eta):
        def g(D):
            x = D / (math.sqrt(2.0) * dt)
            return J * math.sinh(delta_tr - D) - (sigma_y + eta * x ** h) / math.sqrt(2.0)
        if g(0.0) <= 0.0:
            return 0.0
        lo, hi = 0.0, delta_tr
        while hi - lo > 1e-16 * delta_tr:
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            lo, hi = (mid, hi) if g(mid) > 0.0 else (lo, mid)
        return 0.5 * (lo + hi)

    rng = np.random.default_rng(7)
    flowing = 0
    for h in (0.3, 0.5, 1.0, 1.0101, 1.7, 10.0):
        for sigma_y in (1e-6, 0.1):
            for eta in (1e-3, 1.0):
                for dt in (1e-4, 0.3):
                    for _ in range(5):
                        J = rng.uniform(0.7, 1.3)
                        delta_tr = rng.uniform(0.01, 2.0)
                        got = plastic_decrement(J, delta_tr, dt, sigma_y, h, eta)
                        want = reference(J, delta_tr, dt, sigma_y, h, eta)
                        flowing += want > 0.0
                        assert abs(got - want) <= 1e-14 * delta_tr, (h, sigma_y, eta, dt)
    assert flowing > 200  # the cases flow: the root, not the elastic branch, is compared

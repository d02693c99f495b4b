"""Model kernels: bitwise cancellation of each bond's pair terms, damage, detached
correspondence points."""

import numpy as np
import pytest

from hpcmpm.pd.correspondence import Correspondence, correspondence_bond_forces
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS, lps_bond_forces
from hpcmpm.pd.pmb import PMB, pmb_bond_forces
from hpcmpm.materials.linear_elastic import _stress_2d, _stress_3d


def random_body(dim, name, seed=0):
    rng = np.random.default_rng(seed)
    n = 7 if dim == 3 else 12
    x0 = np.stack(np.meshgrid(*[np.arange(n, dtype=float)] * dim, indexing="ij"),
                  -1).reshape(-1, dim) + rng.uniform(-0.3, 0.3, (n ** dim, dim))
    ids = rng.permutation(len(x0)).astype(np.int64) * 3 + 5   # ids unrelated to rows
    fam = find_families(x0, ids, len(x0), 1.0, 3.015)
    kernel = _stress_3d if dim == 3 else _stress_2d
    model = {"pmb": lambda: PMB(1.3),
             "lps": lambda: LPS(1.0, 0.7),
             "correspondence": lambda: Correspondence(
                 dim, lambda F, tau: kernel(np.ascontiguousarray(F), tau, 0.7, 0.4), 0.13)}[name]()
    body = PDBody(x0, rng.uniform(0.5, 1.5, len(x0)), ids, 1.0, fam, model)
    body.pts.x[:] = x0 + 0.05 * rng.standard_normal(x0.shape)    # a non-affine state
    return body


def bond_terms(body):
    m, p, b = body.model, body.pts, body.pts.bonds
    out = np.empty((b.n_bonds, body.dim))
    args = (p.x, p.x0, p.vol, b.offsets, b.slot, b.status, b.weight)
    if m.name == "pmb":
        pmb_bond_forces(*args, m.c, p.n_owned, out)
    elif m.name == "lps":
        lps_bond_forces(*args, p.fields["m"], m.theta, m.kappa, m.mu, p.n_owned, out)
    else:
        correspondence_bond_forces(*args, m.A, m.F, m.active, m.G, p.n_owned, out)
    return out


def bond_geometry(body):
    """(owner, X, Y) of every half-bond of ``body``: its owner's row and the reference and
    current bond vectors, for the numpy statements of the force states below."""
    b, pts = body.pts.bonds, body.pts
    owner = np.repeat(np.arange(b.n), b.counts())
    return owner, pts.x0[b.slot] - pts.x0[owner], pts.x[b.slot] - pts.x[owner]


@pytest.mark.parametrize("name", ["pmb", "lps", "correspondence"])
@pytest.mark.parametrize("dim", [2, 3])
def test_pair_terms_cancel_bitwise(dim, name):
    body = random_body(dim, name)
    body.compute_forces()
    b = body.pts.bonds
    terms = bond_terms(body)
    owner = np.repeat(np.arange(b.n), b.counts())
    # The reverse half-bond of (p -> q) is (q -> p): find it by (owner, slot) pairs.
    index = {(int(o), int(s)): k for k, (o, s) in enumerate(zip(owner, b.slot))}
    reverse = np.array([index[(int(s), int(o))] for o, s in zip(owner, b.slot)])
    assert np.array_equal(terms, -terms[reverse])       # bitwise, not approximately
    # and the force kernel sums exactly these terms (in partner-id order)
    sums = np.zeros_like(body.force)
    for k in range(b.n):
        for t in terms[b.offsets[k]:b.offsets[k + 1]]:
            sums[k] += t
    assert np.array_equal(sums, body.force)


def test_damage_counts_weighted_broken_volume():
    body = random_body(2, "pmb", seed=1)
    b = body.pts.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    x0 = body.pts.x0
    across = (x0[owner, 0] < 5.5) != (x0[b.slot, 0] < 5.5)
    b.status[across] = 0
    vol = body.pts.vol
    want = np.array([np.sum((b.weight * vol[b.slot] * across)[owner == k]) /
                     np.sum((b.weight * vol[b.slot])[owner == k]) for k in range(b.n)])
    np.testing.assert_allclose(body.damage(), want, rtol=1e-13, atol=1e-15)
    assert body.damage().max() > 0.3


def test_detached_correspondence_point_carries_no_stress():
    body = random_body(2, "correspondence", seed=2)
    b = body.pts.bonds
    # Particle 0 keeps one bond (its partner keeps the other end): K is rank 1.
    keep = b.offsets[0]
    partner = b.slot[keep]
    b.status[b.offsets[0] + 1:b.offsets[1]] = 0
    owner = np.repeat(np.arange(b.n), b.counts())
    b.status[(b.slot == 0) & (owner != partner)] = 0
    body.pts.x[:] *= 1.3                      # a large stretch: stress everywhere
    body.compute_forces()
    m = body.model
    assert m.active[0] == 0.0 and np.array_equal(m.F[0], np.eye(2))
    assert np.all(m.A[0] == 0.0) and np.all(np.isfinite(body.force))
    # The only force on 0 comes from its partner's side of the one bond.
    terms = bond_terms(body)
    assert np.array_equal(body.force[0], terms[keep])


@pytest.mark.parametrize("dim", [2, 3])
def test_lps_pair_terms_match_the_force_state_written_out(dim):
    """The LPS kernels fold each end's scalar force state into per-point coefficients
    (lps.end_coefficients); the pair terms must equal the force state as the issue writes
    it, evaluated here with numpy from the bond lists alone: m_p = sum w |X|^2 V_q,
    theta_p = (d/m_p) sum w |X| e V_q, t_p = (d kappa theta_p/m_p)|X| + (alpha_m/m_p)(e -
    theta_p |X|/d), term = w (t_p + t_q) V_p V_q Y/|Y|, at a non-affine state. rtol 1e-12:
    the same quantities rounded and summed in another order (measured: 4.4e-16 of the
    largest term in 2D, 3.5e-16 in 3D). Fails with a sign slip in the coefficients."""
    body = random_body(dim, "lps", seed=3)
    body.compute_forces()
    b, pts, model = body.pts.bonds, body.pts, body.model
    owner, X, Y = bond_geometry(body)
    q = b.slot
    xl, yl = np.linalg.norm(X, axis=1), np.linalg.norm(Y, axis=1)
    e = yl - xl
    wv = b.weight * pts.vol[q]
    m = np.bincount(owner, wv * xl ** 2, b.n)
    theta = dim / m * np.bincount(owner, wv * xl * e, b.n)
    alpha_m = (15.0 if dim == 3 else 8.0) * model.mu
    t = lambda k: (dim * model.kappa * theta[k] / m[k]) * xl + \
        (alpha_m / m[k]) * (e - theta[k] * xl / dim)  # noqa: E731
    want = (b.weight * (t(owner) + t(q)) * pts.vol[owner] * pts.vol[q] / yl)[:, None] * Y
    got = bond_terms(body)
    assert np.abs(theta).max() > 1e-3                   # a deformed, non-affine state
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize("dim", [2, 3])
def test_pmb_pair_terms_match_the_pair_force_written_out(dim):
    """PMB divides once a bond (a = c w V_p V_q e / (|X| |Y|)); the terms must equal the
    pair force as 003 eq. 4.3 (corrected) writes it, c s w V_p V_q Y/|Y| with
    s = (|Y| - |X|)/|X|, evaluated with numpy. rtol 1e-13: a few roundings apart
    (measured: 2.7e-16 of the largest term in 2D, 2.4e-16 in 3D)."""
    body = random_body(dim, "pmb", seed=4)
    body.compute_forces()
    b, pts = body.pts.bonds, body.pts
    owner, X, Y = bond_geometry(body)
    xl, yl = np.linalg.norm(X, axis=1), np.linalg.norm(Y, axis=1)
    s = (yl - xl) / xl
    want = (body.model.c * s * b.weight * pts.vol[owner] * pts.vol[b.slot] / yl)[:, None] * Y
    got = bond_terms(body)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13 * np.abs(want).max())


@pytest.mark.parametrize("dim", [2, 3])
def test_correspondence_pair_terms_match_the_force_state_written_out(dim):
    """The correspondence terms, the zero-energy-mode control included, against the module
    docstring's force evaluated with numpy from the model's A, F and active: term =
    [w (A_p + A_q) X + (G w/|X|)(a_p (Y - F_p X) + a_q (Y - F_q X))] V_p V_q at a
    non-affine state, then the control's terms alone (A = 0), so that a slip in either part
    is seen by itself (a halved G was caught before only by a NaN in a stability test).
    rtol 1e-12: the same quantities rounded and summed in another order."""
    body = random_body(dim, "correspondence", seed=5)
    body.compute_forces()
    b, pts, m = body.pts.bonds, body.pts, body.model
    owner, X, Y = bond_geometry(body)
    q = b.slot
    wv = (b.weight * pts.vol[owner] * pts.vol[q])[:, None]
    stress = wv * np.einsum("bij,bj->bi", m.A[owner] + m.A[q], X)
    z = lambda k: m.active[k][:, None] * (Y - np.einsum("bij,bj->bi", m.F[k], X))  # noqa: E731
    control = (m.G / np.linalg.norm(X, axis=1))[:, None] * wv * (z(owner) + z(q))
    want = stress + control
    got = bond_terms(body)
    scale = np.abs(want).max()
    assert m.G > 0.0 and np.abs(control).max() > 1e-3 * scale   # the control acts here
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale)
    # The control alone: the same terms with A = 0.
    m.A[:] = 0.0
    np.testing.assert_allclose(bond_terms(body), control, rtol=1e-12,
                               atol=1e-12 * np.abs(control).max())

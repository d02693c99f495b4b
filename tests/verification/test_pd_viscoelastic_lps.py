"""Viscoelastic linearized LPS (003 eq. 5.12-5.20 as corrected by the issue;
hpcmpm/pd/viscoelastic_lps.py): the modulus state is the derivative of the LPS force state
(Taylor remainder slope 2), tau = inf reproduces the total-Lagrangian LPS (hpcmpm/pd/lps.py)
to O(eps^2), a held shear relaxes as exp(-t/tau), steady shear gives the Maxwell stress
mu tau gamma_dot, and memory = "none" (eq. 5.14 literally) is a viscosity mu dt."""

import math

import numpy as np
import pytest

from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDPoints
from hpcmpm.pd.lps import LPS, lps_bond_forces
from hpcmpm.pd.viscoelastic_lps import ViscoelasticLPS, modulus_state
from pd_helpers import lattice

DELTA = 3.015
RADIUS = DELTA + 0.5
K, MU = 2.0, 1.2


def points(dim, n, jitter=0.2, seed=0):
    rng = np.random.default_rng(seed)
    x0, ids = lattice(dim, n)
    x0 = x0 + rng.uniform(-jitter, jitter, x0.shape)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    return PDPoints(x0.copy(), x0.copy(), np.ones(len(x0)), ids, len(x0), fam.bonds)


def lps_force_state(X, Y, w, V, dim):
    """Force state T<i> = w t dir(Y) of one point (the LPS as the issue writes it: m, theta,
    e^d over the point's bonds, reference X, deformed Y), written here independently."""
    alpha_m = (15.0 if dim == 3 else 8.0) * MU
    xl = np.linalg.norm(X, axis=1)
    yl = np.linalg.norm(Y, axis=1)
    m = np.sum(w * xl ** 2 * V)
    e = yl - xl
    theta = dim / m * np.sum(w * xl * e * V)
    t = dim * K * theta / m * xl + alpha_m / m * (e - theta * xl / dim)
    return (w * t)[:, None] * Y / yl[:, None]


@pytest.mark.parametrize("dim", [2, 3])
def test_modulus_state_is_the_derivative_of_the_lps_force_state(dim):
    # Linearize about a deformed configuration Y0 (taken as the reference, eq. 5.17) and
    # perturb by eps U: |T(Y0 + eps U) - eps M U| must fall as eps^2 (Taylor remainder).
    pts = points(dim, 9 if dim == 2 else 7)
    rng = np.random.default_rng(1)
    y0 = pts.x0 @ (np.eye(dim) + 0.05 * rng.standard_normal((dim, dim))).T
    p = int(np.argmin(np.linalg.norm(pts.x0 - pts.x0.mean(0), axis=1)))
    b = pts.bonds
    M = modulus_state(y0, pts.vol, b, p, K, MU)
    q = b.slot[b.offsets[p]:b.offsets[p + 1]]
    w = b.weight[b.offsets[p]:b.offsets[p + 1]]
    Y0 = y0[q] - y0[p]
    U = rng.standard_normal(Y0.shape)
    predicted = np.einsum("ijab,jb,j->ia", M, U, pts.vol[q])
    eps = np.array([4e-3, 2e-3, 1e-3, 5e-4])
    rem = [np.abs(lps_force_state(Y0, Y0 + e * U, w, pts.vol[q], dim) - e * predicted).max()
           for e in eps]
    slope = np.polyfit(np.log(eps), np.log(rem), 1)[0]
    # A first-order-wrong M gives slope 1; round-off (1e-16 of forces ~ eps) is far below
    # the remainders (~eps^2 ~ 1e-7).
    assert abs(slope - 2.0) < 0.05, (slope, rem)


def shear_path(dim, x0, s, amplitude):
    """A smooth non-affine deformation with a finite rotation, s in [0, 1]."""
    c, sn = math.cos(0.4 * s), math.sin(0.4 * s)
    R = np.eye(dim)
    R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -sn, sn, c
    u = np.zeros_like(x0)
    u[:, 0] = np.sin(0.3 * x0[:, 1]) + 0.5 * x0[:, 0]
    u[:, 1] = np.cos(0.2 * x0[:, 0]) * x0[:, 1] * 0.3
    if dim == 3:
        u[:, 2] = np.sin(0.25 * x0[:, 0] + 0.1 * x0[:, 2])
    return (x0 + s * amplitude * u) @ R.T


def ve_final_force(dim, amplitude, steps=20):
    pts = points(dim, 12 if dim == 2 else 7)
    model = ViscoelasticLPS(K, MU)          # tau = inf
    model.setup(pts)
    model.dt = 1.0
    f = np.empty((pts.n_owned, dim))
    for k in range(1, steps + 1):
        pts.x[:] = shear_path(dim, pts.x0, k / steps, amplitude)
        model.update_state(pts)
        model.forces(pts, f)
    lps = LPS(K, MU)
    lps.setup(pts)
    lps.update_state(pts)
    g = np.empty_like(f)
    lps.forces(pts, g)
    return f, g


@pytest.mark.parametrize("dim", [2, 3])
def test_infinite_tau_matches_total_lagrangian_lps_to_second_order(dim):
    errs, scales = [], []
    for amp in (2e-3, 1e-3):
        f, g = ve_final_force(dim, amp)
        errs.append(np.abs(f - g).max())
        scales.append(np.abs(g).max())
    # Forces ~ amp, their difference ~ amp^2 (m and the increments use |Y_ref| for |X|):
    # halving the strain divides the difference by 4 (3.6-4.4: the O(amp^3) terms at
    # amp ~ 1e-3 are a few per cent of the leading one).
    assert 3.6 < errs[0] / errs[1] < 4.4, errs
    assert errs[1] < 1e-2 * scales[1]
    assert 1.9 < scales[0] / scales[1] < 2.1


def affine_points(dim, n, gamma):
    pts = points(dim, n, jitter=0.0)
    pts.x[:] = pts.x0
    pts.x[:, 0] += gamma * pts.x0[:, 1]
    return pts


def interior(x0, n):
    return np.all((x0 >= 2 * RADIUS) & (x0 <= n - 1 - 2 * RADIUS), axis=1)


def virial_shear(pts, pair_force, rows):
    """sigma_xy = (1/(2 V_p)) sum_q f_pq,x Y_y per point (the pair forces of a homogeneous
    state), averaged over ``rows``."""
    b = pts.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    Y = pts.x[b.slot] - pts.x[owner]
    s = np.zeros(b.n)
    np.add.at(s, owner, 0.5 * pair_force[:, 0] * Y[:, 1] / pts.vol[owner])
    return s[rows].mean()


def stored_pair_forces(pts, pairs):
    """The pair forces (ve_iso + ve_dev) V_p V_q Y/|Y| of the step whose stored forces
    ``pairs`` the model returned."""
    b = pts.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    Y = pts.x[b.slot] - pts.x[owner]
    a = pairs.sum(axis=1) * pts.vol[owner] * pts.vol[b.slot]
    return (a / np.linalg.norm(Y, axis=1))[:, None] * Y * (b.status[:, None] != 0)


N_SHEAR = 20


def lattice_shear_modulus():
    """mu of the discrete lattice: sigma_xy / gamma of the total-Lagrangian LPS (lps.py) under
    a small affine shear, interior points."""
    gamma = 1e-6
    pts = affine_points(2, N_SHEAR, gamma)
    lps = LPS(K, MU)
    lps.setup(pts)
    lps.update_state(pts)
    out = np.empty((pts.bonds.n_bonds, 2))
    b = pts.bonds
    lps_bond_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                    pts.fields["m"], lps.theta, K, MU, pts.n_owned, out)
    return virial_shear(pts, out, interior(pts.x0, N_SHEAR)) / gamma


def run_shear(model, rate, dt, steps, hold=0):
    """Affine simple shear gamma = rate t for ``steps`` steps, then held for ``hold`` steps;
    returns the points, the stored forces (ve_iso, ve_dev) of the last step and ve_dev
    after each held step."""
    pts = affine_points(2, N_SHEAR, 0.0)
    model.setup(pts)
    model.dt = dt
    f = np.empty((pts.n_owned, 2))
    pairs = np.empty((pts.bonds.n_bonds, 2))
    for k in range(1, steps + 1):
        pts.x[:, 0] = pts.x0[:, 0] + rate * k * dt * pts.x0[:, 1]
        model.update_state(pts)
        model.forces(pts, f, pairs=pairs)
    held = []
    for _ in range(hold):
        model.update_state(pts)
        model.forces(pts, f, pairs=pairs)
        held.append(pairs[:, 1].copy())
    return pts, pairs, held


def test_held_shear_relaxes_exponentially():
    tau, dt = 1.0, 0.1
    model = ViscoelasticLPS(K, MU, relaxation_time=tau)
    pts, pairs, held = run_shear(model, 1e-3 / dt, dt, steps=1, hold=40)
    start = held[0]
    big = np.abs(start) > 1e-3 * np.abs(start).max()
    assert big.sum() > 100
    for k, s in enumerate(held[1:], start=1):
        # Held positions: the increments vanish exactly, so s_dev(t) = s_dev(t0) g^k with
        # g = exp(-dt/tau); the only error is k roundings of the product (k <= 40 ulp).
        rel = np.abs(s[big] / start[big] - math.exp(-k * dt / tau)).max()
        assert rel < 1e-12, (k, rel)
    # Interior points of a shear have theta = O(gamma^2): the isotropic part stays small.
    b = pts.bonds
    inner = np.repeat(interior(pts.x0, N_SHEAR), b.counts())
    assert np.abs(pairs[inner, 0]).max() < 1e-2 * np.abs(start[inner]).max()
    # The stored forces are the state (memory = "maxwell"): what the step returned.
    assert np.array_equal(b.state["ve_iso"], pairs[:, 0])
    assert np.array_equal(b.state["ve_dev"], pairs[:, 1])


def test_steady_shear_gives_maxwell_stress():
    tau, dt = 1.0, 0.05
    rate = 1e-4 / tau                 # gamma_dot tau = 1e-4: linear regime
    mu_lat = lattice_shear_modulus()
    # mu_lat differs from mu by the lattice sum of the partial-volume family (measured
    # -3.85 %): against mu itself the stress is 3.86 % low, outside the 2 %, which
    # is the discrete solid's modulus, not the model's error (docs/studies.md).
    assert -0.045 < mu_lat / MU - 1.0 < -0.03
    model = ViscoelasticLPS(K, MU, relaxation_time=tau)
    steps = int(round(10 * tau / dt))          # transient exp(-10) = 5e-5
    pts, pairs, _ = run_shear(model, rate, dt, steps)
    sigma = virial_shear(pts, stored_pair_forces(pts, pairs), interior(pts.x0, N_SHEAR))
    # Maxwell: sigma -> mu tau gamma_dot (1 - exp(-t/tau)). Measured -3.8e-5, the transient
    # exp(-10) = 4.5e-5; the bound 2e-3 (the issue asks 2 %) leaves room for the O(gamma)
    # geometric terms (gamma = 1e-3) and no more.
    assert abs(sigma / (mu_lat * tau * rate) - 1.0) < 2e-3, sigma / (mu_lat * tau * rate)


def test_memory_none_is_a_viscosity_proportional_to_dt():
    rate = 1e-3
    ratios = []
    for dt in (0.02, 0.01):
        model = ViscoelasticLPS(K, MU, memory="none")
        pts, pairs, _ = run_shear(model, rate, dt, steps=10)
        sigma = virial_shear(pts, stored_pair_forces(pts, pairs), interior(pts.x0, N_SHEAR))
        ratios.append(sigma / (lattice_shear_modulus() * rate * dt))
    # The force is the last step's increment: sigma = mu gamma_dot dt, i.e. a viscosity
    # eta = mu dt; 1 % covers O(gamma) terms (gamma <= 2e-4).
    for r in ratios:
        assert abs(r - 1.0) < 0.01, ratios


def test_bond_state_is_bitwise_symmetric_and_forces_cancel():
    pts = points(2, 10)
    model = ViscoelasticLPS(K, MU, relaxation_time=0.5)
    model.setup(pts)
    model.dt = 0.1
    f = np.empty((pts.n_owned, 2))
    rng = np.random.default_rng(5)
    for _ in range(5):
        pts.x += 1e-3 * rng.standard_normal(pts.x.shape)
        model.update_state(pts)
        model.forces(pts, f)
    b = pts.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    pos = {(int(o), int(q)): k for k, (o, q) in enumerate(zip(owner, b.slot))}
    mirror = np.array([pos[(int(q), int(o))] for o, q in zip(owner, b.slot)])
    for name in ("ve_len", "ve_iso", "ve_dev"):
        assert np.array_equal(b.state[name], b.state[name][mirror]), name
    assert np.abs(f.sum(axis=0)).max() < 1e-13 * np.abs(f).sum()


def run_isotropic(model, dt, stretches):
    """Isotropic stretch x = x0 (1 + s) through ``stretches`` (one step each); returns the
    points, the interior-bond mask and the stored ve_iso after each step."""
    pts = affine_points(2, N_SHEAR, 0.0)
    model.setup(pts)
    model.dt = dt
    f = np.empty((pts.n_owned, 2))
    pairs = np.empty((pts.bonds.n_bonds, 2))
    iso = []
    for s in stretches:
        pts.x[:] = pts.x0 * (1.0 + s)
        model.update_state(pts)
        model.forces(pts, f, pairs=pairs)
        iso.append(pairs[:, 0].copy())
    inner = np.repeat(interior(pts.x0, N_SHEAR), pts.bonds.counts())
    return pts, inner, iso


def test_isotropic_part_does_not_relax():
    # Only the deviatoric extension is viscous (Silling 2010 / Mitchell 2011 VES; 003 eq.
    # 5.12-5.20): an isotropic stretch s = 1e-3 applied in one step and held 10 steps of
    # dt = 0.1 with tau = 1 keeps ve_iso. Held positions give exactly zero increments, so
    # ve_iso is bitwise unchanged (measured ratio exactly 1.0); a model that also decays it
    # by exp(-dt/tau) gives exp(-1) = 0.3679 at the end.
    model = ViscoelasticLPS(K, MU, relaxation_time=1.0)
    _, inner, iso = run_isotropic(model, 0.1, [1e-3] * 11)
    start = iso[0][inner]
    assert np.abs(start).min() > 0.0
    for k, s in enumerate(iso[1:], start=1):
        rel = np.abs(s[inner] / start - 1.0).max()
        assert rel < 1e-12, (k, rel)


def test_memory_none_keeps_only_the_last_isotropic_increment():
    # memory = "none" (eq. 5.14 literally) drops the stored force: ve_iso is the current
    # step's isotropic increment w (t_p,iso + t_q,iso). A constant-rate ramp x = x0 (1 + a k),
    # a = 1e-4, gives equal displacement increments a|X|, so the increments agree up to the
    # linearization about Y_ref = x0 (1 + a (k - 1)): t_iso ~ theta |Y_ref| / m ~ (1 + a(k-1))^-2,
    # ve_iso(10) / ve_iso(5) = ((1 + 4a) / (1 + 9a))^2 = 0.99900. Measured on interior bonds:
    # median 0.99900 (the formula to 1e-13; all bonds within 2e-12 of it), max |r - 1|
    # 1.0e-3; the 1e-2 bound is 10x that and far from the 2 (to O(a)) of a model that
    # accumulates ve_iso (measured median 1.999).
    a = 1e-4
    model = ViscoelasticLPS(K, MU, memory="none")
    _, inner, iso = run_isotropic(model, 0.01, [a * k for k in range(1, 11)])
    r = iso[9][inner] / iso[4][inner]
    assert abs(np.median(r) - ((1 + 4 * a) / (1 + 9 * a)) ** 2) < 1e-8, np.median(r)
    assert np.abs(r - 1.0).max() < 1e-2, np.abs(r - 1.0).max()


def test_memory_none_stores_no_forces():
    # memory = "none" keeps the lengths only (one state array a bond, not three), and its
    # force is the step's increment alone: the force of a Maxwell model with tau = inf
    # (decay = gain = 1) whose stored forces are zeroed before every step. The two evaluate
    # the same expression in the same order, so they agree bit for bit; a "none" model that
    # kept (or read) a stored force would differ from the second step on.
    none = ViscoelasticLPS(K, MU, memory="none")
    zeroed = ViscoelasticLPS(K, MU)
    a, b = points(2, 10), points(2, 10)
    none.setup(a)
    zeroed.setup(b)
    assert sorted(a.bonds.state) == ["ve_len"]
    assert sorted(b.bonds.state) == ["ve_dev", "ve_iso", "ve_len"]
    none.dt = zeroed.dt = 0.1
    fa, fb = np.empty((a.n_owned, 2)), np.empty((b.n_owned, 2))
    rng = np.random.default_rng(7)
    for _ in range(4):
        u = 1e-3 * rng.standard_normal(a.x.shape)
        a.x += u
        b.x += u
        b.bonds.state["ve_iso"][:] = 0.0
        b.bonds.state["ve_dev"][:] = 0.0
        for model, pts, f in ((none, a, fa), (zeroed, b, fb)):
            model.update_state(pts)
            model.forces(pts, f)
        assert np.abs(fa).max() > 0.0
        assert np.array_equal(fa, fb)
        assert np.array_equal(a.bonds.state["ve_len"], b.bonds.state["ve_len"])

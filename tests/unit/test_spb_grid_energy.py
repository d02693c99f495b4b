"""Eigenerosion energy on the grid (003 eq. 6.10 as corrected in issue 11): the tensile part
of the stress against numpy's eigendecomposition, G_i under uniform uniaxial tension,
compression and pure shear at nodes with full particle support, the history EE_p, and the
node flags."""

import itertools

import numpy as np
import pytest

from hpcmpm.kernels.shape import evaluate
from hpcmpm.kernels.transfer import static
from hpcmpm.pd import grid_energy as ge

L0 = 0.3          # l0 = delta; any positive length
E, NU = 7.0e3, 0.3


def tensile_reference(sigma):
    """sigma+ = sum_k max(s_k, 0) n_k n_k^T by numpy.linalg.eigh (independent of the kernels)."""
    w, V = np.linalg.eigh(sigma)
    return (V * np.maximum(w, 0.0)) @ V.T


def phi_reference(sigma, code):
    sp = tensile_reference(sigma)
    pp = np.sum(sp * sp)
    if code == ge.STRESS_SQUARED:
        return pp
    return ((1 + NU) * pp - NU * np.trace(sp) ** 2) / (2 * E)


def random_symmetric(rng, dim, n):
    A = rng.normal(size=(n, dim, dim))
    return 0.5 * (A + A.transpose(0, 2, 1))


@pytest.mark.parametrize("dim", [2, 3])
def test_tensile_part_matches_eigh(dim):
    rng = np.random.default_rng(3)
    S = random_symmetric(rng, dim, 400)
    # Repeated and zero eigenvalues (uniaxial stress, hydrostatic states, rank one).
    Q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    for diag in ([2.0, 0.0, 0.0], [-1.0, -1.0, 3.0], [1.0, 1.0, 1.0], [-2.0, 0.0, 0.0],
                 [1e-9, -1.0, 5.0]):
        S = np.concatenate([S, (Q @ np.diag(diag[:dim]) @ Q.T)[None]])
    for s in S:
        if dim == 2:
            got = np.array(ge.tensile_part_2d(s[0, 0], s[0, 1], s[1, 1]))
            ref = tensile_reference(s)[[0, 0, 1], [0, 1, 1]]
        else:
            got = np.array(ge.tensile_part_3d(s[0, 0], s[0, 1], s[0, 2], s[1, 1], s[1, 2],
                                              s[2, 2]))
            ref = tensile_reference(s)[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
        # Both are backward stable eigensolvers: agreement to a few ulps of |sigma|.
        assert np.abs(got - ref).max() <= 1e-13 * max(np.abs(s).max(), 1.0)


def lattice_particles(dim, n_cells, ppc, dx):
    """Particles at ((k + 1/2)/ppc) dx over n_cells cells per axis (the project's sampling)."""
    axis = (np.arange(n_cells * ppc) + 0.5) * dx / ppc
    x = np.array(list(itertools.product(axis, repeat=dim)), dtype=np.float64)
    return x


def scatter_G(dim, sigma, code, dx=0.5, n_cells=8, ppc=2, J=1.0):
    """G_i over a block for particles all holding Cauchy stress sigma (tau = J sigma with
    F = J^(1/d) I); returns (G, interior mask of nodes whose full support is filled)."""
    x = lattice_particles(dim, n_cells, ppc, dx)
    n = len(x)
    rng = np.random.default_rng(7)
    mass = rng.uniform(0.5, 2.0, n)          # unequal masses: G must still be exact
    F = np.broadcast_to(J ** (1.0 / dim) * np.eye(dim), (n, dim, dim)).copy()
    tau = np.broadcast_to(J * sigma, (n, dim, dim)).copy()
    EE = np.zeros(n)
    shape = (n_cells + 4,) * dim
    origin = np.full(dim, -2, dtype=np.int64)
    e = np.zeros(shape)
    ge.ENERGY_HISTORY[dim](x, mass, tau, F, EE, code, E, NU, static(2), dx, np.zeros(dim),
                           origin, e)
    # m_i = sum_p w_ip m_p from the shape functions directly (independent of the kernel).
    base, w, _ = evaluate(x / dx, 2, 1.0 / dx)
    m = np.zeros(shape)
    for p in range(n):
        for offs in itertools.product(range(3), repeat=dim):
            node = tuple(base[p, a] + offs[a] - origin[a] for a in range(dim))
            m[node] += mass[p] * np.prod([w[p, a, offs[a]] for a in range(dim)])
    G = np.empty(shape)
    assert ge.grid_energy_release(e, m, L0, G) == G.max()
    # Node i (global) has full support when every cell it touches is filled: 2 <= i <= n - 2
    # (quadratic B-spline reach 1.5 cells).
    idx = np.arange(shape[0]) + origin[0]
    inside = (idx >= 2) & (idx <= n_cells - 2)
    mask = np.ones(shape, dtype=bool)
    for a in range(dim):
        mask &= inside.reshape([-1 if b == a else 1 for b in range(dim)])
    return G, mask


def rotation(dim, rng):
    Q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    return Q


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("code", [ge.STRESS_SQUARED, ge.TENSILE_ENERGY])
def test_uniaxial_tension_compression_and_shear(dim, code):
    rng = np.random.default_rng(5)
    s0 = 37.0
    Q = rotation(dim, rng)
    n = Q[:, 0]
    uniaxial = s0 * np.outer(n, n)
    G, mask = scatter_G(dim, uniaxial, code, J=1.3)
    expect = L0 * s0 ** 2 if code == ge.STRESS_SQUARED else L0 * s0 ** 2 / (2 * E)
    # G_i = l0 sum w m EE / sum w m with one EE value: exact up to the rounding of the sums
    # and of the eigensolver (a few ulps).
    assert np.abs(G[mask] / expect - 1).max() < 1e-12
    assert mask.sum() >= 5 ** dim
    Gc, _ = scatter_G(dim, -uniaxial, code)
    # Compression has no tensile part: not even round-off (the 2D/3D branches return 0).
    assert np.abs(Gc).max() <= 1e-12 * expect
    tau = 11.0
    m2 = Q[:, 1]
    shear = tau * (np.outer(n, m2) + np.outer(m2, n))     # principal values +tau, -tau
    Gs, _ = scatter_G(dim, shear, code)
    expect_s = L0 * tau ** 2 if code == ge.STRESS_SQUARED else L0 * tau ** 2 / (2 * E)
    assert np.abs(Gs[mask] / expect_s - 1).max() < 1e-12


@pytest.mark.parametrize("dim", [2, 3])
def test_history_never_decreases(dim):
    rng = np.random.default_rng(9)
    n = 50
    EE = np.zeros(n)
    running = np.zeros(n)
    F = np.broadcast_to(np.eye(dim), (n, dim, dim)).copy()
    x = rng.uniform(2.0, 3.0, (n, dim))
    grid = np.zeros((6,) * dim)
    for step in range(20):
        S = random_symmetric(rng, dim, n) * rng.uniform(0.1, 3.0)
        before = EE.copy()
        ge.ENERGY_HISTORY[dim](x, np.ones(n), S, F, EE, ge.TENSILE_ENERGY, E, NU, static(2),
                               1.0, np.zeros(dim), np.zeros(dim, np.int64), grid)
        running = np.maximum(running, [phi_reference(s, ge.TENSILE_ENERGY) for s in S])
        assert np.all(EE >= before)
        np.testing.assert_allclose(EE, running, rtol=1e-12, atol=0)


def test_flags_cells_with_a_flagged_corner():
    dim, dx = 2, 1.0
    shape = (6, 6)
    origin = np.zeros(2, np.int64)
    G = np.zeros(shape)
    G[3, 2] = 10.0                            # only node (3, 2) reaches the threshold
    x = np.array([[2.5, 1.5], [2.5, 2.5], [3.5, 2.5], [1.5, 1.5], [3.2, 3.9], [3.5, 0.5]])
    v = np.zeros_like(x)
    model = np.array([0, 0, 0, 0, 0, 1], np.int8)
    out = np.empty(len(x), np.int64)
    count, margin = ge.FLAGGED_PARTICLES[2](x, v, 0.1, np.arange(len(x), dtype=np.int64), model,
                                            G, 10.0, np.zeros(dim), dx, origin, out)
    # Cells (2,1), (2,2), (3,2) have node (3,2) as a corner; (1,1) and (3,3) do not; the
    # last particle is already PD.
    assert sorted(out[:count].tolist()) == [0, 1, 2]
    assert margin == 0.0


def test_flags_by_the_cell_at_the_p2g_position():
    """The cell is the one at x^n = x - dt v (the step's P2G position), not at x."""
    dim, dx = 2, 1.0
    origin = np.zeros(2, np.int64)
    G = np.zeros((6, 6))
    G[3, 2] = 10.0                            # only node (3, 2) reaches the threshold
    x = np.array([[4.5, 2.5], [2.5, 2.5]])
    v = np.array([[10.0, 0.0], [10.0, 0.0]])
    model = np.zeros(len(x), np.int8)
    out = np.empty(len(x), np.int64)
    count, _ = ge.FLAGGED_PARTICLES[2](x, v, 0.1, np.arange(len(x), dtype=np.int64), model,
                                       G, 10.0, np.zeros(dim), dx, origin, out)
    # x^n = (3.5, 2.5) lies in cell (3, 2) (corner (3, 2) flagged) and (1.5, 2.5) in cell
    # (1, 2) (corners (1..2, 2..3), none flagged); at x the cells (4, 2) and (2, 2) would
    # flag particle 1 instead.
    assert out[:count].tolist() == [0]


@pytest.mark.parametrize("corner", list(itertools.product((0, 1), repeat=3)))
def test_flags_3d_by_any_corner_of_the_cell_at_the_p2g_position(corner):
    """3D: each of the 8 corners of the cell at x^n = x - dt v flags the particle; the cell
    at x (two cells further along every axis) does not count. The second particle's x^n
    cell touches no flagged node, its x cell does."""
    dx, dt = 1.0, 0.1
    origin = np.zeros(3, np.int64)
    G = np.zeros((8, 8, 8))
    node = tuple(2 + c for c in corner)
    G[node] = 10.0                                  # only this node reaches the threshold
    x_n = np.array([[2.5, 2.5, 2.5], [0.5, 0.5, 0.5]])
    v = np.full((2, 3), 20.0)                       # dt v = two cells along each axis
    x = x_n + dt * v                                # cells (4, 4, 4) and (2, 2, 2)
    model = np.zeros(2, np.int8)
    out = np.empty(2, np.int64)
    count, margin = ge.FLAGGED_PARTICLES[3](x, v, dt, np.arange(2, dtype=np.int64), model, G,
                                            10.0, np.zeros(3), dx, origin, out)
    assert out[:count].tolist() == [0]
    assert margin == 0.0
    model[0] = 1                                    # already PD: not flagged again
    count, _ = ge.FLAGGED_PARTICLES[3](x, v, dt, np.arange(2, dtype=np.int64), model, G, 10.0,
                                       np.zeros(3), dx, origin, out)
    assert count == 0


def test_tensile_energy_with_a_negative_poisson_ratio_is_not_skipped():
    """3D skips the eigen-solve when Phi <= c sigma:sigma cannot exceed the history EE_p;
    for tensile_energy c = max(1 + nu, 1 - 2 nu) / (2E). With nu < 0 the bound is (1 - 2nu)
    / (2E): hydrostatic tension s has sigma+ = sigma, sigma+:sigma+ = sigma:sigma = 3 s^2,
    (tr sigma+)^2 = 9 s^2, Phi = (3 (1 + nu) - 9 nu) s^2 / (2E) = 5.4 s^2 / (2E) at nu = -0.4,
    above (1 + nu) sigma:sigma / (2E) = 1.8 s^2 / (2E). A history EE_p = 0.8 Phi must be
    raised to Phi."""
    nu, s = -0.4, 5.0
    F = np.eye(3)[None].copy()
    tau = (s * np.eye(3))[None].copy()
    phi = (3 * (1 + nu) - 9 * nu) * s ** 2 / (2 * E)
    x = np.full((1, 3), 2.5)
    for start in (0.0, 0.8 * phi):
        EE = np.array([start])
        ge.ENERGY_HISTORY[3](x, np.ones(1), tau, F, EE, ge.TENSILE_ENERGY, E, nu, static(2),
                             1.0, np.zeros(3), np.zeros(3, np.int64), np.zeros((6, 6, 6)))
        # rel 1e-14: a few products of exact small numbers (measured equal to the last bit).
        assert EE[0] == pytest.approx(phi, rel=1e-14)

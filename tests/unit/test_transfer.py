"""Transfers: P2G conservation and the angular momentum of APIC/MLS (Jiang 2015 §5.3)."""

import numpy as np
import pytest

from hpcmpm.kernels.particles import momentum_and_kinetic_energy
from hpcmpm.kernels.shape import CUBIC, QUADRATIC, inverse_inertia_factor
from hpcmpm.kernels.transfer import APIC, FLIP, GATHER, MLS, PIC, SCATTER, static

DX = 0.1


def random_particles(dim, n=400, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(1.0, 2.0, size=(n, dim))
    mass = rng.uniform(0.5, 1.5, size=n)
    return rng, x, mass


def block_for(x, dim):
    """Node box covering every particle's support (cells -1 .. +2 around each)."""
    cells = np.floor(x / DX).astype(np.int64)
    origin = cells.min(axis=0) - 1
    shape = tuple(cells.max(axis=0) - origin + 3)
    return origin, shape


def transfer_cycle(x, v, C, F, mass, scheme, order, dim):
    origin, shape = block_for(x, dim)
    grid_mass = np.zeros(shape)
    grid_mom = np.zeros(shape + (dim,))
    tau = np.zeros((len(x), dim, dim))
    vol = np.full(len(x), 1e-3)
    lo = np.zeros(dim)
    dinv = inverse_inertia_factor(order)
    SCATTER[dim](x, v, C, mass, vol, tau, static(scheme), static(order), dinv, DX, lo, origin,
                 0.0, static(False), grid_mass, grid_mom, grid_mom)
    vel = np.zeros_like(grid_mom)
    has = grid_mass > 0
    vel[has] = grid_mom[has] / grid_mass[has][:, None]
    # dt = 0: positions and F stay put, so repeated cycles measure the transfer alone.
    GATHER[dim](x, v, C, F, static(scheme), static(order), dinv, DX, lo, origin, 0.0, 1.0,
                vel, vel)
    return grid_mass, grid_mom


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
@pytest.mark.parametrize("scheme", [PIC, FLIP, APIC, MLS])
def test_p2g_conserves_mass_and_momentum(dim, order, scheme):
    rng, x, mass = random_particles(dim)
    v = rng.normal(size=x.shape)
    C = rng.normal(size=(len(x), dim, dim))
    F = np.tile(np.eye(dim), (len(x), 1, 1))
    grid_mass, grid_mom = transfer_cycle(x, v, C, F, mass, scheme, order, dim)
    # Partition of unity and sum_i w (x_i - x_p) = 0 make both exact up to round-off of
    # summing ~400 * 27 terms: 1e-12 relative is a few hundred ulps of headroom.
    assert abs(grid_mass.sum() - mass.sum()) <= 1e-12 * mass.sum()
    p_particles = (mass[:, None] * v).sum(axis=0)
    scale = np.abs(mass[:, None] * v).sum()
    assert np.all(np.abs(grid_mom.reshape(-1, dim).sum(axis=0) - p_particles) <= 1e-12 * scale)


def angular_momentum(x, v, mass, C, scheme, order):
    inertia = DX * DX / inverse_inertia_factor(order)
    out = momentum_and_kinetic_energy(x, v, mass, C, scheme >= APIC, inertia)
    return out[3:6]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
def test_affine_transfers_keep_angular_momentum_pic_loses_it(dim, order):
    """Random velocities and affine matrices, not a rigid rotation: an affine field is
    reproduced exactly by any transfer that is exact for affine fields, so a rigid rotation
    would keep its angular momentum even under a G2P whose C does not conserve it (e.g. the
    gradient form sum_i v_i grad w_ip^T, which loses 0.1-0.6 % here in 10 cycles)."""
    rng, x, mass = random_particles(dim, seed=3)
    v0 = rng.normal(size=(len(x), dim))
    C0 = rng.normal(size=(len(x), dim, dim))
    results = {}
    for scheme in (PIC, APIC, MLS):
        xs = x.copy()
        v = v0.copy()
        C = C0.copy() if scheme >= APIC else np.zeros((len(x), dim, dim))
        F = np.tile(np.eye(dim), (len(x), 1, 1))
        L0 = angular_momentum(xs, v, mass, C, scheme, order)
        for _ in range(10):
            transfer_cycle(xs, v, C, F, mass, scheme, order, dim)
        L1 = angular_momentum(xs, v, mass, C, scheme, order)
        results[scheme] = np.linalg.norm(L1 - L0) / np.linalg.norm(L0)
    # APIC/MLS conserve angular momentum exactly in exact arithmetic (Jiang 2015 Thm. 5.3);
    # 10 cycles of round-off stay far below 1e-10.
    assert results[APIC] < 1e-10
    assert results[MLS] < 1e-10
    # PIC dissipates the rotation: it loses a visible fraction in 10 cycles.
    assert results[PIC] > 1e-3


def gather(x, v, field, field_old, scheme, order, dim, dt, alpha, F=None, origin=None):
    """One G2P of a given grid velocity on the `block_for` box; returns (x, v, C, F)."""
    x, v = x.copy(), v.copy()
    if origin is None:
        origin, _ = block_for(x, dim)
    C = np.zeros((len(x), dim, dim))
    F = np.tile(np.eye(dim), (len(x), 1, 1)) if F is None else F.copy()
    GATHER[dim](x, v, C, F, static(scheme), static(order), inverse_inertia_factor(order), DX,
                np.zeros(dim), origin, dt, alpha, np.ascontiguousarray(field),
                np.ascontiguousarray(field_old))
    return x, v, C, F


@pytest.mark.parametrize("dim", [2, 3])
def test_flip_gather_blends_and_advects_with_pic_velocity(dim):
    """FLIP/PIC blend (Stomakhin 2013 §7, Jiang 2015 §3, Hu 2018 MLS-MPM): the particle
    velocity becomes alpha (v_p + sum_i w_ip (v_i - v_i^old)) + (1 - alpha) sum_i w_ip v_i,
    while the position moves with the PIC velocity u = sum_i w_ip v_i, not the FLIP one."""
    rng, x, _ = random_particles(dim, n=200, seed=1)
    v = rng.normal(size=x.shape)
    _, shape = block_for(x, dim)
    vel = rng.normal(size=shape + (dim,))
    old = rng.normal(size=shape + (dim,))
    alpha, dt = 0.95, 0.01
    _, u, _, _ = gather(x, v, vel, vel, PIC, QUADRATIC, dim, 0.0, 0.0)
    _, du, _, _ = gather(x, v, vel - old, vel, PIC, QUADRATIC, dim, 0.0, 0.0)
    x_new, v_flip, _, _ = gather(x, v, vel, old, FLIP, QUADRATIC, dim, dt, alpha)
    # Same sums, regrouped: measured 4.4e-16 in v and 0 in x, with |u| <= 2. 1e-12 leaves
    # round-off headroom; swapped weights are off by 0.86 relative, and advecting with the
    # FLIP velocity moves x by ~1.5 dt |u| (~3e-2) from x + dt u.
    assert np.abs(v_flip - (alpha * (v + du) + (1 - alpha) * u)).max() <= 1e-12
    assert np.abs(x_new - (x + dt * u)).max() <= 1e-12


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
@pytest.mark.parametrize("scheme", [PIC, FLIP, APIC, MLS])
def test_gather_of_affine_field_is_exact(dim, order, scheme):
    """Linear completeness of the B-spline transfers: for a grid velocity v_i = A x_i + b,
    sum_i v_i grad w_ip^T = A (gradient form, 000 eq. 3.7) and D^-1 sum_i w_ip v_i
    (x_i - x_p)^T = A (APIC C, Jiang 2015 eq. 11; MLS grad v, Hu 2018 eq. 17), so
    F <- (I + dt A) F exactly and C = A. A is non-symmetric, so grad v and its transpose
    differ."""
    rng, x, _ = random_particles(dim, n=100, seed=2)
    origin, shape = block_for(x, dim)
    A = rng.normal(size=(dim, dim))
    b = rng.normal(size=dim)
    nodes = (np.stack(np.indices(shape), -1) + origin) * DX
    vel = nodes @ A.T + b
    F0 = np.eye(dim) + 0.1 * rng.normal(size=(len(x), dim, dim))
    dt = 0.01
    x_new, v_new, C, F = gather(x, np.zeros_like(x), vel, vel, scheme, order, dim, dt, 0.0,
                                F=F0, origin=origin)
    want_v = x @ A.T + b
    # Measured: |F - (I + dt A) F0| / dt <= 4.7e-14 and |C - A| <= ~1e-13 (round-off of
    # 27-64 term sums of O(10) products); 1e-11 keeps two decades of headroom, while the
    # transposed grad v is off by 3.35.
    assert np.abs(F - (np.eye(dim) + dt * A) @ F0).max() <= 1e-11 * dt
    assert np.abs(v_new - want_v).max() <= 1e-11
    assert np.abs(x_new - (x + dt * want_v)).max() <= 1e-11 * dt
    if scheme >= APIC:
        assert np.abs(C - A).max() <= 1e-11


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
@pytest.mark.parametrize("scheme", [PIC, FLIP, APIC, MLS])
def test_scatter_force_moment_is_minus_dt_v0_tau(dim, order, scheme):
    """The internal-force impulse of one particle has first moment
    sum_i f_i (x_i - x_p)^T = -dt V0 tau for the gradient form f_i = -dt V0 tau grad w_ip
    (000 eq. 3.1; sum_i grad w_ip (x_i - x_p)^T = I) and for MLS's -dt V0 D^-1 tau
    (x_i - x_p) (Hu 2018 eq. 18; D^-1 sum_i w_ip (x_i - x_p)(x_i - x_p)^T = I). A
    non-symmetric tau tells tau from tau^T."""
    rng = np.random.default_rng(3)
    x = rng.uniform(1.0, 2.0, size=(1, dim))
    tau = rng.normal(size=(1, dim, dim))
    vol = np.array([0.3])
    dt = 0.01
    origin, shape = block_for(x, dim)
    gm = np.zeros(shape)
    mom = np.zeros(shape + (dim,))
    imp = np.zeros(shape + (dim,))
    SCATTER[dim](x, np.zeros((1, dim)), np.zeros((1, dim, dim)), np.ones(1), vol, tau,
                 static(scheme), static(order), inverse_inertia_factor(order), DX, np.zeros(dim),
                 origin, dt, static(True), gm, mom, imp)
    nodes = (np.stack(np.indices(shape), -1) + origin) * DX
    moment = imp.reshape(-1, dim).T @ (nodes - x[0]).reshape(-1, dim)
    scale = dt * vol[0] * np.abs(tau).max()
    # Measured <= 1.4e-15 relative; 1e-12 is round-off headroom, tau^T gives 0.20.
    assert np.abs(moment + dt * vol[0] * tau[0]).max() <= 1e-12 * scale

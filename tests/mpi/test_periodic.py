"""Periodic axes: the grid halo folds the nodes beyond a periodic face onto the owned nodes of
the other side (on one rank too), migration wraps positions and gives a crossing particle to
exactly one owner, the particle halo delivers periodic images, and a whole run through a
periodic boundary conserves momentum and agrees across rank counts."""

import numpy as np
import pytest
from mpi4py import MPI

from hpcmpm.parallel import Communicator, Domain
from hpcmpm.runner import simulate
from hpcmpm.scene import parse_scene
from mpi_helpers import (block_grid, cloud, deposit, gather_by_id, particle_set, reference_grid,
                         strided_share)

# (dim, dx, particles, periodic axes, domain upper corner): 2D periodic in x only (y has
# walls), 3D in x and z; then periodic axes narrower than a particle's support (nodes -1 ..
# n + 1): one cell, where that support is node 0 four times, and two cells (3D: 2 in x, 1 in z).
CASES = ((2, 1.0 / 16, 1500, (0,), (1.0, 1.0)), (3, 1.0 / 8, 800, (0, 2), (1.0, 1.0, 1.0)),
         (2, 1.0 / 16, 600, (0,), (1.0 / 16, 1.0)), (3, 1.0 / 8, 500, (0, 2), (0.25, 1.0, 0.125)))


def periodic_cloud(dim, n, seed, periodic, upper):
    """A cloud slightly wider than the unit box on the wall axes and wrapped into [0, upper)
    on the periodic ones, so nodes beyond every face are in somebody's support."""
    values = cloud(dim, n, seed=seed, lo=-0.02, hi=1.02)
    for a in periodic:
        values["x"][:, a] = np.mod(values["x"][:, a], upper[a])
    return values


def folded_reference(values, domain, periodic):
    """The one-process grid of all particles, with every node beyond a periodic face added to
    its image inside: node i of a periodic axis of n cells is node i mod n."""
    origin, m, mom = reference_grid(values, domain)
    for a in periodic:
        n = int(domain.n_cells[a])
        index = (np.arange(m.shape[a]) + origin[a]) % n
        folded_m = np.zeros(m.shape[:a] + (n,) + m.shape[a + 1:])
        folded_mom = np.zeros(mom.shape[:a] + (n,) + mom.shape[a + 1:])
        # np.add.at sums in index order: the reference's own fixed order.
        np.add.at(folded_m, (slice(None),) * a + (index,), m)
        np.add.at(folded_mom, (slice(None),) * a + (index,), mom)
        m, mom = folded_m, folded_mom
    return origin, m, mom


def on_block(field, origin, grid, periodic, n_cells):
    """The reference values at every node of the block, through the periodic wrap."""
    index = []
    for a in range(grid.dim):
        g = np.arange(grid.shape[a]) + grid.origin[a]
        index.append(g % n_cells[a] if a in periodic else g - origin[a])
    return field[np.ix_(*index)]


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_periodic_sum_then_fill_equals_wrapped_one_process():
    for dim, dx, n, periodic, upper in CASES:
        domain = Domain(dim, dx, np.zeros(dim), upper, periodic=periodic)
        values = periodic_cloud(dim, n, 40 + dim, periodic, upper)
        p = particle_set(dim, values, strided_share(values, domain))
        domain.decompose(p)
        for a in periodic:  # the boxes tile [0, n) exactly on a periodic axis
            assert domain.boxes[:, 0, a].min() == 0
            assert domain.boxes[:, 1, a].max() == domain.n_cells[a]
        grid = block_grid(domain, p)
        # The support reaches beyond the periodic faces: the fold is exercised.
        assert any(grid.origin[a] < 0 or grid.origin[a] + grid.shape[a] > domain.n_cells[a]
                   for a in periodic)
        m, mom, touched = deposit(p["x"], p["id"], p["mass"], p["v"], domain.domain_lo,
                                  domain.dx, grid.origin, grid.shape)
        grid["mass"][...] = m
        grid["momentum"][...] = mom
        origin, ref_m, ref_mom = folded_reference(values, domain, periodic)
        block_m = on_block(ref_m, origin, grid, periodic, domain.n_cells)
        block_mom = on_block(ref_mom, origin, grid, periodic, domain.n_cells)

        # Signed momentum sums in another order differ in the last bits of near-cancelling
        # nodes: the absolute tolerance follows the largest value (as in test_grid_halo).
        scale = 1e-13 * np.abs(ref_mom).max()
        domain.sum_ghosts_to_owners(grid, "mass", "momentum")
        owned = np.zeros(grid.shape, dtype=bool)
        owned[domain.owned_slices(grid)] = True
        np.testing.assert_allclose(grid["mass"][owned], block_m[owned], rtol=1e-13, atol=0)
        np.testing.assert_allclose(grid["momentum"][owned], block_mom[owned], rtol=1e-13,
                                   atol=scale)
        # Every folded node is owned exactly once: the owned sums add up to the whole grid.
        assert domain.dot(grid, "mass", "mass") == pytest.approx(float(np.sum(ref_m ** 2)),
                                                                 rel=1e-12)

        grid["mass"][~owned] = np.nan
        grid["momentum"][~owned] = np.nan
        domain.fill_ghosts(grid, "mass", "momentum")
        np.testing.assert_allclose(grid["mass"][touched], block_m[touched], rtol=1e-13, atol=0)
        np.testing.assert_allclose(grid["momentum"][touched], block_mom[touched], rtol=1e-13,
                                   atol=scale)


@pytest.mark.parallel(ranks=[1, 4])
def test_periodic_particles_migrate_and_halo():
    # Two checks in one launch: an mpiexec start costs more than the checks. (2 ranks: the
    # grid-halo and whole-run tests cover them; the CI time budget keeps this at 1 and 4.)
    check_particle_crossing_a_periodic_face_is_wrapped_and_owned_once()
    check_particle_halo_returns_periodic_images()


def check_particle_crossing_a_periodic_face_is_wrapped_and_owned_once():
    dim, periodic = 2, (0,)
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.ones(dim), periodic=periodic)
    values = cloud(dim, 600, seed=8)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    before = gather_by_id(domain, p)
    # Every particle moves by +-0.6 in x (half leave through a face) and a little in y.
    shift = np.where(p["id"] % 2 == 0, 0.6, -0.6)
    p["x"][:, 0] += shift
    p["x"][:, 1] += 0.01
    domain.migrate_all(p)
    after = gather_by_id(domain, p)

    np.testing.assert_array_equal(after["id"], before["id"])  # each id exactly once
    expected_x = before["x"][:, 0] + np.where(before["id"] % 2 == 0, 0.6, -0.6)
    wrapped = np.mod(expected_x, 1.0)
    # x <- lo + (x - lo) mod L: exact up to the rounding of one subtraction and one addition.
    np.testing.assert_allclose(after["x"][:, 0], wrapped, rtol=0, atol=4e-16)
    assert np.all((after["x"][:, 0] >= 0.0) & (after["x"][:, 0] < 1.0))
    assert np.any(expected_x >= 1.0) and np.any(expected_x < 0.0)
    for name in ("v", "mass", "F", "Fp", "tag"):
        np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    momentum = (after["mass"][:, None] * after["v"]).sum(axis=0)
    np.testing.assert_array_equal(momentum, (before["mass"][:, None] * before["v"]).sum(axis=0))
    assert np.all(domain.owners(p["x"]) == domain.rank)
    # A position outside the domain has the owner of its image.
    outside = np.array([[1.3, 0.5], [-0.7, 0.5]])
    np.testing.assert_array_equal(domain.owners(outside), domain.owners(np.mod(outside, 1.0)))


def periodic_neighbour_sum(x_i, x_all, mass_all, r, length, periodic):
    """s_i = sum over particles j and their images within r of x_i of m_j exp(-d^2 / r^2)."""
    total = np.zeros(len(x_i))
    for image in ((-1, 0, 1) if 0 in periodic else (0,)):
        shifted = x_all.copy()
        shifted[:, 0] += image * length
        d2 = ((x_i[:, None, :] - shifted[None, :, :]) ** 2).sum(axis=-1)
        total += np.where(d2 < r * r, mass_all[None, :] * np.exp(-d2 / (r * r)), 0.0).sum(axis=1)
    return total


def check_particle_halo_returns_periodic_images():
    dim, periodic, r = 2, (0,), 0.09
    domain = Domain(dim, 1.0 / 20, np.zeros(dim), np.ones(dim), periodic=periodic)
    values = cloud(dim, 900, seed=31)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    halo = domain.particle_halo(p, r, ["id", "x", "mass"])

    # Images across the face: x outside the domain by at most r, and exactly +-1 from the
    # original particle's x (one addition of the period).
    index = np.searchsorted(values["id"], halo["id"])
    offset = halo["x"][:, 0] - values["x"][index, 0]
    images = offset != 0.0
    assert np.any(images)
    np.testing.assert_allclose(np.abs(offset[images]), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(halo["x"][:, 1], values["x"][index, 1])
    assert np.all(np.abs(halo["x"][images, 0] - 0.5) < 0.5 + r)
    # Own particles come back only as images, never as plain copies.
    own = np.isin(halo["id"], p["id"])
    assert np.all(images[own])

    x_all = np.concatenate([p["x"], halo["x"]])
    m_all = np.concatenate([p["mass"], halo["mass"]])
    d2 = ((p["x"][:, None, :] - x_all[None, :, :]) ** 2).sum(axis=-1)
    mine = np.where(d2 < r * r, m_all[None, :] * np.exp(-d2 / (r * r)), 0.0).sum(axis=1)
    reference = periodic_neighbour_sum(values["x"][np.searchsorted(values["id"], p["id"])],
                                       values["x"], values["mass"], r, 1.0, periodic)
    np.testing.assert_allclose(mine, reference, rtol=1e-12, atol=0)


SCENE = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 0.5] }}
dx = 0.03125
particles_per_cell = 2
periodic = ["x"]
dt = 1e-3
end_time = {end}

[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1000.0
E = 1e4
nu = 0.3

[[bodies]]
name = "block"
material = "rubber"
shape = "box"
lower = [0.7, 0.15]
upper = [0.95, 0.35]
velocity = [3.2, 0.0]
angular_velocity = 1.5

[walls]
default = "sticky"
"""
STEPS = 100


def run_block(comm) -> tuple[dict, list]:
    scene = parse_scene(SCENE.format(end=STEPS * 1e-3))
    momenta = []
    sim = simulate(scene, observer=lambda s: momenta.append(s.diagnostics()["momentum"]),
                   comm=Communicator(comm))
    return gather_by_id(sim.domain, sim.particles), momenta


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_block_through_periodic_faces_conserves_momentum_and_matches_one_rank():
    """A spinning elastic block flies through the x faces (gravity 0, sticky walls in y that
    it never touches): the total momentum is conserved to round-off and the result on N ranks
    equals the 1-rank run (computed on each rank alone) to 1e-10."""
    got, momenta = run_block(MPI.COMM_WORLD)
    # The 1-rank run once, on rank 0, for everybody.
    reference = run_block(MPI.COMM_SELF)[0] if MPI.COMM_WORLD.rank == 0 else None
    reference = MPI.COMM_WORLD.bcast(reference)
    start = sample_momentum()
    scale = np.abs(start).max()
    drift = np.abs(np.array(momenta)[:, :2] - start).max() / scale
    # MLS P2G and G2P conserve momentum exactly in exact arithmetic; 100 steps of round-off.
    assert drift < 1e-12, drift
    x = got["x"]
    # Every particle crossed x = 1 (3.2 m/s for 0.1 s from 0.7 .. 0.95, straddling the face on
    # the way) and sits inside the domain again.
    assert np.all((x[:, 0] >= 0.0) & (x[:, 0] < 0.35))
    for name in ("id", "x", "v", "F"):
        err = np.abs(got[name] - reference[name]).max() / np.abs(reference[name]).max()
        # Only the summation order of ghost contributions differs between rank counts.
        assert err < 1e-10, (name, err)


def sample_momentum():
    scene = parse_scene(SCENE.format(end=1e-3))
    from hpcmpm.geometry import sample_scene

    values = sample_scene(scene)
    return (values["mass"][:, None] * values["v"]).sum(axis=0)


def test_wrap_keeps_inside_points_and_maps_the_upper_face_to_the_lower():
    domain = Domain(2, 0.25, [-1.0, 0.0], [1.0, 1.0], periodic=(0,), comm=MPI.COMM_SELF)
    x = np.array([[0.3, 0.5], [1.0, 0.5], [-1.0, 0.5], [1.75, 2.0], [-3.5, -1.0]])
    wrapped = x.copy()
    moved = domain.wrap(wrapped)
    assert moved == 3  # 1.0 (the upper face), 1.75 and -3.5
    np.testing.assert_array_equal(wrapped[:, 0], [0.3, -1.0, -1.0, -0.25, 0.5])
    np.testing.assert_array_equal(wrapped[:, 1], x[:, 1])  # y is not periodic
    # A coordinate a hair below lo: (x - lo) mod L rounds to L; its image is lo itself.
    hair = np.array([[-1.0 - 2.3e-16, 0.5]])
    domain.wrap(hair)
    assert -1.0 <= hair[0, 0] < 1.0
    # Reference positions move with x by the same whole periods (L = 2), exactly: x - x0
    # stays the displacement, 0.3 here, wherever the particle is.
    x = np.array([[0.3, 0.5], [1.0, 0.5], [-1.0, 0.5], [1.75, 2.0], [-3.5, -1.0]])
    x0 = x - 0.3
    follow = x0.copy()
    domain.wrap(x, follow)
    np.testing.assert_array_equal(follow - x0, [[0, 0], [-2, 0], [0, 0], [-2, 0], [4, 0]])
    assert np.abs((x - follow) - 0.3).max() < 1e-15



ONE_CELL = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 1.0] }}
dx = 1.0
end_time = 0.01
gravity = [0.0, -9.81]
periodic = [{axes}]

[[materials]]
name = "m"
type = "neo_hookean"
density = 1000.0
E = 1e4
nu = 0.3

[[bodies]]
material = "m"
shape = "box"
lower = [0.0, 0.0]
upper = [1.0, 1.0]
velocity = [1.0, 0.0]
"""


@pytest.mark.parallel(ranks=[2, 4])
def test_a_domain_of_fewer_cells_than_ranks_runs():
    """One cell, periodic in x (and in x and y), on more ranks than cells: a rank without a
    box and the ranks beside it list each other (`neighbour_ranks`; the full rank listed the
    empty one, which did not list it back, and the run hung in the neighbour collectives). It
    ends and agrees with the 1-rank run."""
    for axes in ('"x"', '"x", "y"'):
        scene = parse_scene(ONE_CELL.format(axes=axes))
        sim = simulate(scene, comm=Communicator(MPI.COMM_WORLD))
        got = gather_by_id(sim.domain, sim.particles)
        if MPI.COMM_WORLD.rank == 0:
            one = simulate(scene, comm=Communicator(MPI.COMM_SELF))
            reference = gather_by_id(one.domain, one.particles)
        else:
            reference = None
        reference = MPI.COMM_WORLD.bcast(reference)
        assert sim.time == pytest.approx(0.01)
        for name in ("id", "x", "v"):
            # Ghost sums in another order only.
            assert np.allclose(got[name], reference[name], rtol=1e-12, atol=1e-14), name

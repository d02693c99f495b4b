"""Grid halo: after `sum_ghosts_to_owners` every owned node holds the one-process sum; after
`fill_ghosts` every node a rank's particles touch holds the owner's value; `dot` counts each
node once. 4 ranks in 2D make a 2x2 bisection (diagonal neighbours); 3D too."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from hpcmpm.parallel.decomposition import BIG
from mpi_helpers import (block_grid, cloud, deposit, particle_set, reference_grid, strided_share,
                         with_fields_of_id)

CASES = {2: dict(dx=1.0 / 16, n=1500), 3: dict(dx=1.0 / 8, n=800)}


def scattered_grid(dim):
    case = CASES[dim]
    domain = Domain(dim, case["dx"], np.zeros(dim), np.ones(dim))
    # A cloud slightly larger than the domain: nodes beyond the walls get exchanged as well.
    values = cloud(dim, case["n"], seed=dim, lo=-0.02, hi=1.02)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    grid = block_grid(domain, p)
    m, mom, touched = deposit(p["x"], p["id"], p["mass"], p["v"], domain.domain_lo, domain.dx,
                              grid.origin, grid.shape)
    grid["mass"][...] = m
    grid["momentum"][...] = mom
    return domain, values, p, grid, touched


def reference_on_block(values, domain, grid):
    origin, m, mom = reference_grid(values, domain)
    s = tuple(slice(int(o - r), int(o - r) + n) for o, r, n in zip(grid.origin, origin, grid.shape))
    return m[s], mom[s], float(np.sum(m * m)), float(np.sum(mom * mom))


def owned_mask(domain, grid):
    mask = np.zeros(grid.shape, dtype=bool)
    mask[domain.owned_slices(grid)] = True
    return mask


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_sum_then_fill_equals_one_process():
    # Both dimensions in one launch: an mpiexec start costs more than the checks.
    for dim in (2, 3):
        check_sum_then_fill_equals_one_process(dim)


def check_sum_then_fill_equals_one_process(dim):
    domain, values, p, grid, touched = scattered_grid(dim)
    ref_m, ref_mom, ref_mm, ref_pp = reference_on_block(values, domain, grid)

    # Momentum sums signed terms: the summation order changes the last bits of near-cancelling
    # nodes, so the absolute tolerance is set by the largest value.
    scale = 1e-13 * np.abs(ref_mom).max()
    domain.sum_ghosts_to_owners(grid, "mass", "momentum")
    owned = owned_mask(domain, grid)
    np.testing.assert_allclose(grid["mass"][owned], ref_m[owned], rtol=1e-13, atol=0)
    np.testing.assert_allclose(grid["momentum"][owned], ref_mom[owned], rtol=1e-13, atol=scale)
    # No contribution lost: the owned parts of all blocks add up to the whole reference grid.
    assert domain.dot(grid, "mass", "mass") == pytest.approx(ref_mm, rel=1e-12)
    assert domain.dot(grid, "momentum", "momentum") == pytest.approx(ref_pp, rel=1e-12)
    # The m^power-weighted sums (the semi-implicit solve's uniform translation) over all
    # ranks' owned nodes: each node once, like the dot products.
    _, full_m, full_mom = reference_grid(values, domain)
    for power in (1, 2):
        w = (full_m ** power)[..., None]
        expected = (w * full_mom).reshape(-1, dim).sum(axis=0)
        moment, weight = domain.weighted_sum(grid, "momentum", power)
        np.testing.assert_allclose(moment, expected, rtol=1e-12,
                                   atol=1e-13 * np.abs(expected).max())
        assert weight == pytest.approx(w.sum(), rel=1e-12)

    # Poison every ghost node, then let the owners refill what this rank's particles touch.
    grid["mass"][~owned] = np.nan
    grid["momentum"][~owned] = np.nan
    domain.fill_ghosts(grid, "mass", "momentum")
    np.testing.assert_allclose(grid["mass"][touched], ref_m[touched], rtol=1e-13, atol=0)
    np.testing.assert_allclose(grid["momentum"][touched], ref_mom[touched], rtol=1e-13, atol=scale)
    assert domain.global_count(p) == len(values["id"])


@pytest.mark.parallel(ranks=[1, 4])
def test_block_box_is_support_plus_touched_owned_nodes():
    """The block holds exactly what is needed: its own particles' support and the owned nodes
    other ranks touch, nothing more (checked against the union of all ranks' supports)."""
    dim = 2
    domain, values, p, grid, touched = scattered_grid(dim)
    lo, hi = domain.grid_box(p, 3)
    cells = np.floor((values["x"] - domain.domain_lo) / domain.dx).astype(np.int64)
    owner = domain.owners(values["x"])
    mine = owner == domain.rank
    need_lo, need_hi = cells[mine].min(axis=0) - 1, cells[mine].max(axis=0) + 3
    own_lo, own_hi = domain.boxes[domain.rank]
    for r in set(owner.tolist()) - {domain.rank}:
        s_lo = cells[owner == r].min(axis=0) - 1
        s_hi = cells[owner == r].max(axis=0) + 3
        i_lo, i_hi = np.maximum(s_lo, own_lo), np.minimum(s_hi, own_hi)
        if np.all(i_hi > i_lo):
            need_lo, need_hi = np.minimum(need_lo, i_lo), np.maximum(need_hi, i_hi)
    np.testing.assert_array_equal(lo, need_lo)
    np.testing.assert_array_equal(hi, need_hi)


@pytest.mark.parallel(ranks=[2])
def test_rank_without_particles_has_an_empty_block():
    dim = 2
    domain = Domain(dim, 0.1, np.zeros(dim), np.ones(dim))
    values = cloud(dim, 50, seed=5, lo=0.0, hi=0.3)  # all in the first rank's half
    p = particle_set(dim, values, strided_share(values, domain))
    domain.migrate_all(p)  # the initial even split: rank 1 (x >= 0.5) gets nothing
    lo, hi = domain.grid_box(p, 2)
    owners = set(domain.owners(values["x"]).tolist())
    assert np.all(hi > lo) == (domain.rank in owners)
    grid = block_grid(domain, p)
    grid["mass"][...] = 1.0
    domain.sum_ghosts_to_owners(grid, "mass")
    domain.fill_ghosts(grid, "mass")
    # A reduction over an empty block (it raised on the rank without particles).
    grid["momentum"][...] = 2.0
    moment, weight = domain.weighted_sum(grid, "momentum", 2)
    owned_mass = grid["mass"][domain.owned_slices(grid)]
    expected = domain.sum(float(np.sum(owned_mass ** 2)))
    assert weight == pytest.approx(expected, rel=1e-14) and weight > 0
    np.testing.assert_allclose(moment, 2.0 * expected, rtol=1e-14)


def test_a_region_outside_the_block_is_refused_not_wrapped():
    """`region_slices` turns global node boxes into slices of a block; a box reaching below
    the block's origin would give a negative start, which numpy reads from the far end of
    the block (wrong nodes, no error). It raises instead, naming both boxes."""
    from hpcmpm.parallel.exchange import region_slices

    origin, shape = np.array([4, -2]), (6, 5)
    assert region_slices(np.array([5, -2]), np.array([10, 3]), origin, shape) == (
        slice(1, 6), slice(0, 5))
    for lo, hi in (([3, 0], [6, 2]), ([5, 0], [11, 2]), ([5, -3], [6, 2])):
        with pytest.raises(RuntimeError, match=r"grid block \[\[4, -2\], \[10, 3\]\) does not "
                                               r"hold the exchanged nodes"):
            region_slices(np.array(lo), np.array(hi), origin, shape)


@pytest.mark.parallel(ranks=[2])
def test_new_boxes_with_the_same_supports_get_a_new_exchange_plan():
    """`grid_box` reuses its exchange plan while the support boxes stay the same; the plan
    also depends on who owns which nodes, so adopting other boxes (a rebalance, a checkpoint's
    decomposition) must drop it. Here the cut moves from cell 8 to cell 7 between two clusters
    (cells <= 6 and >= 9) whose supports do not change: node 7 changes owner, and with the old
    plan rank 0's sums on it would never reach rank 1."""
    dim = 2
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.ones(dim))
    rng = np.random.default_rng(9)
    x = rng.uniform(0.05, 0.43, size=(400, dim))
    x[200:, 0] += 0.52  # the second cluster: cells 9 .. 15
    values = with_fields_of_id(np.arange(400, dtype=np.int64) * 3 + 1, x)
    p = particle_set(dim, values, strided_share(values, domain))
    for cut in (8, 7):
        domain.set_boxes([[[-BIG, -BIG], [cut, BIG]], [[cut, -BIG], [BIG, BIG]]])
        domain.migrate_all(p)
        grid = block_grid(domain, p)
        m, mom, _ = deposit(p["x"], p["id"], p["mass"], p["v"], domain.domain_lo, domain.dx,
                            grid.origin, grid.shape)
        grid["mass"][...] = m
        domain.sum_ghosts_to_owners(grid, "mass")
        ref_m, _, ref_mm, _ = reference_on_block(values, domain, grid)
        owned = owned_mask(domain, grid)
        np.testing.assert_allclose(grid["mass"][owned], ref_m[owned], rtol=1e-13, atol=0)
        assert domain.dot(grid, "mass", "mass") == pytest.approx(ref_mm, rel=1e-12)

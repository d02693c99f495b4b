"""Recursive coordinate bisection as a pure function (no MPI: identity reductions)."""

import numpy as np

from hpcmpm.parallel.decomposition import (BIG, neighbour_ranks, owner_ranks, particle_cells,
                                           points_in_boxes, recursive_bisection)
from hpcmpm.parallel.domain import NEIGHBOUR_REACH


def bisect(cells, size, n_cells):
    return recursive_bisection(cells, size, np.asarray(n_cells), lambda a: a, lambda a: a)


def owners_of_cells(cells, boxes):
    inside = np.all((cells[:, None] >= boxes[None, :, 0]) & (cells[:, None] < boxes[None, :, 1]),
                    axis=-1)
    assert np.all(inside.sum(axis=1) == 1), "boxes must tile the index space"
    return inside.argmax(axis=1)


def test_four_ranks_on_a_square_give_a_two_by_two_split_with_a_shared_corner():
    grid = np.stack(np.meshgrid(np.arange(32), np.arange(32), indexing="ij"), -1).reshape(-1, 2)
    boxes = bisect(grid, 4, (32, 32))
    # First cut x = 16 (ties go to the lowest axis), then each half at y = 16.
    expected = np.array([[[-BIG, -BIG], [16, 16]], [[-BIG, 16], [16, BIG]],
                         [[16, -BIG], [BIG, 16]], [[16, 16], [BIG, BIG]]])
    np.testing.assert_array_equal(boxes, expected)
    assert np.all(np.bincount(owners_of_cells(grid, boxes)) == 256)


def test_one_cut_is_within_half_a_cell_slab_of_the_median():
    rng = np.random.default_rng(1)
    cells = np.floor(rng.beta(2.0, 5.0, size=(20000, 3)) * [40, 20, 20]).astype(np.int64)
    boxes = bisect(cells, 2, (40, 20, 20))
    assert boxes[0, 1, 0] < BIG and np.all(boxes[0, 1, 1:] == BIG)  # longest axis: x
    left = np.sum(cells[:, 0] < boxes[0, 1, 0])
    slab = np.bincount(cells[:, 0])[boxes[0, 1, 0] - 1: boxes[0, 1, 0] + 1].max()
    assert abs(left - 10000) <= slab / 2


def test_weighted_cuts_balance_counts_and_tile_space():
    # A cut moves whole slabs of cells: with 40 cells per axis and a skewed cloud, a box of
    # the third level is a handful of slabs wide, hence the loose bound.
    rng = np.random.default_rng(0)
    for dim, size in ((2, 3), (2, 5), (3, 7), (3, 8)):
        cells = np.floor(rng.beta(2.0, 5.0, size=(20000, dim)) * 40).astype(np.int64)
        boxes = bisect(cells, size, (40,) * dim)
        counts = np.bincount(owners_of_cells(cells, boxes), minlength=size)
        assert counts.max() / counts.mean() < 1.2, counts
        assert np.all(boxes[:, 0] < boxes[:, 1])
        np.testing.assert_array_equal(bisect(cells, size, (40,) * dim), boxes)  # deterministic


def test_no_particles_splits_the_domain_evenly_and_the_owner_kernel_agrees():
    boxes = bisect(np.empty((0, 2), np.int64), 2, (10, 10))
    np.testing.assert_array_equal(boxes[:, 1, 0], [5, BIG])
    x = np.array([[0.49, 0.2], [0.51, 0.9], [-3.0, 7.0], [np.nan, 0.0]])
    out = owner_ranks(x, np.zeros(2), 10.0, boxes, 1, np.empty(4, np.int64))
    np.testing.assert_array_equal(out, [0, 1, 0, 1])  # non-finite stays with the caller


def test_no_particles_on_an_odd_rank_count_gives_every_rank_an_equal_strip():
    """Before the first `decompose` (and for a box that holds no particle) the cut follows
    the rank split of the box, not its middle: on 3 ranks the first cut leaves a third, not
    a half, to rank 0. Widths are counted over cells -1 .. n (the wall layers included,
    `_empty_cut`) and differ by a cell at most (rounding to whole cells)."""
    for size in (3, 5, 7):
        n = 10 * size
        boxes = bisect(np.empty((0, 2), np.int64), size, (n, 8))
        assert np.all(boxes[:, 0, 1] == -BIG) and np.all(boxes[:, 1, 1] == BIG)  # x strips
        faces = np.clip(np.concatenate([boxes[:, 0, 0], boxes[-1:, 1, 0]]), -1, n + 1)
        widths = np.diff(faces)
        assert np.all(np.abs(widths - (n + 2) / size) <= 1), (size, widths)
    np.testing.assert_array_equal(bisect(np.empty((0, 2), np.int64), 3, (30, 8))[:, 1, 0],
                                  [10, 20, BIG])


def test_a_particle_on_a_box_face_belongs_to_the_box_above_from_either_side():
    """Boxes are half-open ``[lo, hi)``: a particle exactly on a cut (x = cut * dx, exact in
    binary) is owned by the upper box, whichever rank asks (`owner_ranks` starts from the
    asking rank's own box, `leavers` keeps what that box holds)."""
    boxes = bisect(np.empty((0, 2), np.int64), 4, (16, 16))  # 2 x 2, cuts at 8
    dx = 1.0 / 16
    x = np.array([[8 * dx, 0.1], [0.1, 8 * dx], [8 * dx, 8 * dx], [8 * dx - 1e-12, 0.1]])
    want = [2, 1, 3, 0]
    for me in range(4):
        out = owner_ranks(x, np.zeros(2), 1.0 / dx, boxes, me, np.empty(4, np.int64))
        np.testing.assert_array_equal(out, want, err_msg=f"asked by rank {me}")


def test_points_in_boxes_are_grouped_by_box_and_the_boxes_are_closed():
    """The halo selections (`Domain.particle_halo`, `PDHalo`) ship the points of the closed
    box ``[lo, hi]``, both faces included, a point in two boxes twice, grouped by box."""
    x = np.array([[0.0, 0.0], [1.0, 1.0], [0.5, 1.0], [1.0, 0.2], [1.5, 0.5], [2.0, 2.0]])
    lo = np.array([[0.0, 0.0], [1.0, 0.0]])
    hi = np.array([[1.0, 1.0], [2.0, 1.0]])
    counts, index = points_in_boxes(x, lo, hi)
    np.testing.assert_array_equal(counts, [4, 3])
    np.testing.assert_array_equal(index, [0, 1, 2, 3, 1, 3, 4])


def test_integer_weights_move_the_cuts_to_the_weighted_quantile():
    """`Simulation.load_weights` (a PD particle's bonds) steers the cuts: with the particles
    of x < 10 ten times as heavy, the weight, not the count, is balanced. A cut moves whole
    cell slabs: each rank's weight is within one heavy slab's weight (40 cells * 10 = 400,
    of a total 5200) of the mean. Measured: 2400 / 2800 on 2 ranks, 1600 / 1800 / 1800 on
    3; by count the first cut would fall at x = 20 (weights 4400 / 800)."""
    grid = np.stack(np.meshgrid(np.arange(40), np.arange(40), indexing="ij"), -1).reshape(-1, 2)
    weights = np.where(grid[:, 0] < 10, 10, 1).astype(np.int64)
    for size in (2, 3):
        boxes = recursive_bisection(grid, size, np.array([40, 40]), lambda a: a, lambda a: a,
                                    weights=weights)
        owner = owners_of_cells(grid, boxes)
        load = np.bincount(owner, weights=weights, minlength=size)
        assert np.all(np.abs(load - load.mean()) <= 400), (size, load)
        counts = np.bincount(owner, minlength=size)
        assert counts.max() / counts.mean() > 1.3  # far from balanced: 1.70 and 1.35


def test_particle_cells_floor_and_keep_blown_up_particles_at_cell_0():
    """The cells the bisection histograms: floor((x - lo) / dx), a non-finite coordinate at
    cell 0 (inside the domain, so a blown-up particle cannot stretch a box to +-BIG; the
    instability guard reports it), a huge one just inside the int64-safe range."""
    x = np.array([[0.25, -0.01], [np.nan, 0.5], [np.inf, -np.inf], [1e300, -1e300]])
    np.testing.assert_array_equal(particle_cells(x, np.zeros(2), 8.0),
                                  [[2, -1], [0, 4], [0, 0], [BIG - 1, -BIG]])


def test_neighbours_reach_past_a_thin_box():
    """The grid exchange talks to `neighbour_ranks` only, so they must include every rank
    whose nodes my particles' support (cells lo .. hi-1 touch nodes lo-1 .. hi+1) reaches,
    and every rank whose particles' support reaches mine. Boxes that tile space share faces,
    so a reach of one cell finds those; a box one cell thin puts the rank beyond it two nodes
    from my support's end, which only the full reach finds. Strips along x: [.., 8), [8, 9),
    [9, 11), [11, ..)."""
    faces = [-BIG, 8, 9, 11, BIG]
    boxes = np.array([[[faces[r], -BIG], [faces[r + 1], BIG]] for r in range(4)])
    zero = np.zeros((1, 2), np.int64)
    for me in range(4):
        found = set(neighbour_ranks(boxes, me, zero, NEIGHBOUR_REACH).tolist())
        lo, hi = boxes[me, 0, 0], boxes[me, 1, 0]
        needed = {q for q in range(4) if q != me and (
            (boxes[q, 0, 0] < hi + 2 and boxes[q, 1, 0] > lo - 1)          # my support
            or (lo < boxes[q, 1, 0] + 2 and hi > boxes[q, 0, 0] - 1))}     # theirs
        assert needed <= found, (me, needed, found)
    assert 2 in set(neighbour_ranks(boxes, 0, zero, NEIGHBOUR_REACH).tolist())


def test_neighbours_are_symmetric_also_for_empty_boxes():
    """q is my neighbour exactly when I am q's, whatever the boxes (empty ones included: a
    domain of fewer cells than ranks leaves ranks without a box) and periodic shifts: the
    neighbour collectives wait for every listed rank, so one listing that was not returned
    hung the run (1 periodic cell, 2 ranks)."""
    rng = np.random.default_rng(7)
    shifts = np.array([[0, 0], [5, 0], [-5, 0]])
    for _ in range(200):
        n = int(rng.integers(2, 7))
        lo = rng.integers(0, 5, size=(n, 2))
        size = rng.integers(0, 3, size=(n, 2)) * (rng.random((n, 1)) < 0.7)  # some empty
        boxes = np.stack([lo, lo + size], axis=1)
        lists = [set(neighbour_ranks(boxes, r, shifts, NEIGHBOUR_REACH).tolist())
                 for r in range(n)]
        for r in range(n):
            for q in lists[r]:
                assert r in lists[q], (boxes.tolist(), r, q)
    # An empty box beside a full one: both see each other.
    boxes = np.array([[[0, 0], [1, 1]], [[1, 1], [1, 1]]])
    assert neighbour_ranks(boxes, 0, shifts[:1], NEIGHBOUR_REACH).tolist() == [1]
    assert neighbour_ranks(boxes, 1, shifts[:1], NEIGHBOUR_REACH).tolist() == [0]


def test_cell_count_rounds_a_domain_that_is_a_whole_number_of_cells():
    """0.3 / 0.1 is 2.9999999999999996 in floating point: the domain is 3 cells, not 2 (a
    cell count by floor would drop the last cell column, hence the period of a periodic
    axis and the outer faces of the even start-up split)."""
    from hpcmpm.parallel import Domain

    domain = Domain(2, 0.1, np.zeros(2), np.array([0.3, 0.7]), periodic=(0,))
    np.testing.assert_array_equal(domain.n_cells, [3, 7])
    np.testing.assert_array_equal(domain.period, [3, 0])

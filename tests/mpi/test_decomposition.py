"""Recursive coordinate bisection as a pure function (no MPI: identity reductions)."""

import numpy as np

from hpcmpm.parallel.decomposition import BIG, owner_ranks, recursive_bisection


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

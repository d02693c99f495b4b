"""Sort keys (group, cell): a particle flung far outside the domain (or broken, NaN) cannot
overflow the packed key, so every material's particles stay one contiguous slice."""

import numpy as np
import pytest

from hpcmpm.kernels.particles import cell_sort_keys, counting_sort_order


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("far", [1e30, -1e30, 1e12, np.nan, np.inf])
def test_a_far_particle_keeps_the_group_order(dim, far):
    rng = np.random.default_rng(dim)
    n = 200
    x = rng.uniform(0.0, 1.0, size=(n, dim))
    group = rng.integers(0, 3, size=n).astype(np.int32)
    x[7] = far  # every coordinate of one particle of some group
    x[11, 0] = -far if np.isfinite(far) else 0.5  # and one coordinate of another
    keys = np.empty(n, dtype=np.int64)
    n_keys = cell_sort_keys(x, group, np.zeros(dim), 16.0, keys)
    assert 0 < n_keys < 2**62
    assert keys.min() >= 0 and keys.max() < n_keys
    order = np.argsort(keys, kind="stable")
    sorted_groups = group[order]
    assert np.all(np.diff(sorted_groups) >= 0)  # groups contiguous, in order
    # Particles inside the domain keep their row-major cell order within a group.
    inside = np.all((x >= 0) & (x < 1), axis=1)
    cells = np.floor(x[inside] * 16).astype(np.int64)
    linear = np.ravel_multi_index(cells.T, (16,) * dim)
    ref = np.lexsort((linear, group[inside]))
    got = [i for i in order if inside[i]]
    np.testing.assert_array_equal(np.flatnonzero(inside)[ref], got)


def test_counting_sort_matches_the_keys_in_the_dense_case():
    x = np.random.default_rng(0).uniform(0.0, 1.0, size=(500, 3))
    group = (np.arange(500) % 2).astype(np.int32)
    keys = np.empty(500, dtype=np.int64)
    n_keys = cell_sort_keys(x, group, np.zeros(3), 8.0, keys)
    order = np.empty(500, dtype=np.int64)
    counting_sort_order(keys, n_keys, order, np.empty(n_keys + 1, dtype=np.int64))
    assert np.all(np.diff(keys[order]) >= 0)

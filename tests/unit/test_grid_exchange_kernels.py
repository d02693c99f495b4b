"""The kernels that pack and unpack grid regions for the halo exchange
(`Domain._exchange_regions`; the exchange itself: tests/mpi/test_grid_halo.py and
test_periodic.py). Checked against numpy's fancy indexing, bitwise: both copy, or add one
double at a time in list order."""

import numpy as np

from hpcmpm.kernels.grid import gather_nodes, scatter_nodes


def test_gather_then_scatter_is_numpy_indexing():
    rng = np.random.default_rng(4)
    field = rng.standard_normal((40, 3))
    # A node listed twice: a periodic image that wraps onto the same node (one-cell axis).
    index = np.array([5, 17, 3, 17, 39, 0], dtype=np.int64)
    buf = np.full(2 + index.size * 3, np.nan)
    gather_nodes(field, index, buf, 2)
    assert np.array_equal(buf[2:].reshape(-1, 3), field[index])

    target = rng.standard_normal((40, 3))
    expected = target.copy()
    np.add.at(expected, index, field[index])  # unbuffered: both 17s add, in list order
    added = target.copy()
    scatter_nodes(added, index, buf, 2, True)
    assert np.array_equal(added, expected)

    copied = target.copy()
    scatter_nodes(copied, index, buf, 2, False)
    expected = target.copy()
    expected[index] = field[index]
    assert np.array_equal(copied, expected)

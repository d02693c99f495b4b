"""The documented volume average (hpcmpm/kernels/volume.py; ``simulation.volume_averaging =
"increment"``) in plain numpy, for the tests that check the kernels and the engine against it
(tests/unit/test_volume_averaging.py, tests/mpi/test_volume_averaging_ranks.py)."""

from __future__ import annotations

import numpy as np


def weights_1d(xi: np.ndarray, order: int):
    """(base, w (n, order + 1)): the B-spline weights, written independently of the kernels."""
    if order == 2:
        base = np.floor(xi - 0.5).astype(np.int64)
        r = xi[:, None] - (base[:, None] + np.arange(3))
        a = np.abs(r)
        w = np.where(a < 0.5, 0.75 - a * a, 0.5 * (1.5 - a) ** 2)
    else:
        base = np.floor(xi).astype(np.int64) - 1
        a = np.abs(xi[:, None] - (base[:, None] + np.arange(4)))
        w = np.where(a < 1.0, 0.5 * a ** 3 - a * a + 2.0 / 3.0, (2.0 - a) ** 3 / 6.0)
    return base, w


def reference_average(x, vol0, J_old, J_new, dx, order, periodic_cells=0):
    """J_p^n sum_i w_ip r_i, r_i = sum_q w_iq V0_q J_q^{n+1} / sum_q w_iq V0_q J_q^n, over all
    particles at once; nodes along a periodic x axis wrap modulo its cell count."""
    dim = x.shape[1]
    bases, ws = zip(*(weights_1d(x[:, a] / dx, order) for a in range(dim)))
    s = order + 1
    nodes, w = [], []
    for corner in np.ndindex(*(s,) * dim):
        idx = [bases[a] + corner[a] for a in range(dim)]
        if periodic_cells:
            idx[0] = idx[0] % periodic_cells
        nodes.append(np.stack(idx, axis=1))
        w.append(np.prod([ws[a][:, corner[a]] for a in range(dim)], axis=0))
    keys = np.concatenate(nodes)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(len(nodes), len(x))
    old = np.zeros(len(unique))
    new = np.zeros(len(unique))
    for k in range(len(nodes)):
        np.add.at(old, inverse[k], w[k] * vol0 * J_old)
        np.add.at(new, inverse[k], w[k] * vol0 * J_new)
    r = new / old
    return J_old * sum(w[k] * r[inverse[k]] for k in range(len(nodes)))

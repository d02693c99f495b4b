"""The layout of the semi-implicit solve's particle tangents: T_p = D^2 e_p, the k x k
(k = d^2) second derivative of a particle's incremental potential in its velocity gradient
(000 §5.5, appendix A), stored as its upper triangle, row by row: k (k + 1) / 2 doubles a
particle, 45 in 3D (360 B against 648 for the full matrix) and 10 in 2D.

T_p is symmetric: it is a Hessian. The material kernels give it to round-off (2.8e-11 of its
largest entry where the implicit isochoric return's scalar Newton stops, 4e-16 elsewhere;
measured on the shipped semi-implicit scenes), so the upper triangle is the tangent, and the
grid Hessian the CG applies is then exactly symmetric. A CG iteration reads every tangent
once (`HESSIAN_PRODUCT`); reading 45 doubles instead of 81 did not make that loop faster
(measured, BENCHMARKS.md): the layout saves memory, not time."""

from __future__ import annotations

import numpy as np
from numba import njit


def packed_size(k: int) -> int:
    """Doubles per particle for a k x k tangent."""
    return k * (k + 1) // 2


@njit(cache=True, inline="always")
def packed_index(r, c, k):
    """Position of T[r, c] (= T[c, r]) in the packed row."""
    if r > c:
        r, c = c, r
    return r * k - (r * (r - 1)) // 2 + (c - r)


def index_table(k: int) -> np.ndarray:
    """(k, k) int64: the packed position of every entry (symmetric)."""
    r, c = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    lo, hi = np.minimum(r, c), np.maximum(r, c)
    return lo * k - (lo * (lo - 1)) // 2 + (hi - lo)


def unpack(S: np.ndarray) -> np.ndarray:
    """(n, k, k) symmetric tangents from packed rows (n, k (k + 1) / 2): for tests and
    studies."""
    m = S.shape[-1]
    k = int(round((np.sqrt(8 * m + 1) - 1) / 2))
    assert packed_size(k) == m, m
    return S[..., index_table(k)]


def pack(T: np.ndarray) -> np.ndarray:
    """Packed rows (n, k (k + 1) / 2) of the upper triangles of T (n, k, k)."""
    k = T.shape[-1]
    r, c = np.triu_indices(k)
    return np.ascontiguousarray(T[..., r, c])

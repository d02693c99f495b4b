"""Small-tensor algebra on tuples of scalars, for per-particle loops.

A 2x2 matrix is the tuple ``(a00, a01, a10, a11)``, a 3x3 matrix the row-major tuple
``(a00, a01, a02, a10, ..., a22)``. numba keeps such tuples in registers, so the material
kernels do their algebra without allocating a small array per particle.
"""

from __future__ import annotations

from numba import njit


# -- 2x2 -------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def load2(A, p):
    """A[p] of an (n, 2, 2) array as a tuple."""
    return (A[p, 0, 0], A[p, 0, 1], A[p, 1, 0], A[p, 1, 1])


@njit(cache=True, inline="always")
def store2(A, p, a):
    """A[p] = a for an (n, 2, 2) array."""
    A[p, 0, 0] = a[0]
    A[p, 0, 1] = a[1]
    A[p, 1, 0] = a[2]
    A[p, 1, 1] = a[3]


@njit(cache=True, inline="always")
def mul2(a, b):
    """a b."""
    return (a[0] * b[0] + a[1] * b[2], a[0] * b[1] + a[1] * b[3],
            a[2] * b[0] + a[3] * b[2], a[2] * b[1] + a[3] * b[3])


@njit(cache=True, inline="always")
def mul2_bt(a, b):
    """a b^T."""
    return (a[0] * b[0] + a[1] * b[1], a[0] * b[2] + a[1] * b[3],
            a[2] * b[0] + a[3] * b[1], a[2] * b[2] + a[3] * b[3])


@njit(cache=True, inline="always")
def det2(a):
    return a[0] * a[3] - a[1] * a[2]


@njit(cache=True, inline="always")
def frob2(a):
    """a : a."""
    return a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3]


# -- 3x3 -------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def load3(A, p):
    """A[p] of an (n, 3, 3) array as a row-major tuple."""
    return (A[p, 0, 0], A[p, 0, 1], A[p, 0, 2],
            A[p, 1, 0], A[p, 1, 1], A[p, 1, 2],
            A[p, 2, 0], A[p, 2, 1], A[p, 2, 2])


@njit(cache=True, inline="always")
def store3(A, p, a):
    """A[p] = a for an (n, 3, 3) array."""
    A[p, 0, 0] = a[0]
    A[p, 0, 1] = a[1]
    A[p, 0, 2] = a[2]
    A[p, 1, 0] = a[3]
    A[p, 1, 1] = a[4]
    A[p, 1, 2] = a[5]
    A[p, 2, 0] = a[6]
    A[p, 2, 1] = a[7]
    A[p, 2, 2] = a[8]


@njit(cache=True, inline="always")
def mul3(a, b):
    """a b."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
            a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
            a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
            a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@njit(cache=True, inline="always")
def mul3_bt(a, b):
    """a b^T."""
    return (a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
            a[0] * b[3] + a[1] * b[4] + a[2] * b[5],
            a[0] * b[6] + a[1] * b[7] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[1] + a[5] * b[2],
            a[3] * b[3] + a[4] * b[4] + a[5] * b[5],
            a[3] * b[6] + a[4] * b[7] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[1] + a[8] * b[2],
            a[6] * b[3] + a[7] * b[4] + a[8] * b[5],
            a[6] * b[6] + a[7] * b[7] + a[8] * b[8])


@njit(cache=True, inline="always")
def det3(a):
    return (a[0] * (a[4] * a[8] - a[5] * a[7])
            - a[1] * (a[3] * a[8] - a[5] * a[6])
            + a[2] * (a[3] * a[7] - a[4] * a[6]))


@njit(cache=True, inline="always")
def frob3(a):
    """a : a."""
    s = 0.0
    for k in range(9):
        s += a[k] * a[k]
    return s

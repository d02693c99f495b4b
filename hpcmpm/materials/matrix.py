"""Dimension-generic small-matrix algebra on tuples, for kernels written once for 2D and 3D.

A 2x2 matrix is the 4-tuple and a 3x3 matrix the row-major 9-tuple of
`hpcmpm.materials.tensors`. Each function here is a numba overload that picks the 2x2 or 3x3
implementation from the tuple's length when the caller compiles, so a kernel such as
``mul(a, inverse(b))`` compiles to straight-line scalar code for each dimension, with no branch
on the dimension and no small array per particle. Inverses and determinants are closed forms
(adjugate over determinant), never a decomposition.

A kernel that loads matrices from an (n, d, d) array gets a *witness* tuple (`EYE2` or `EYE3`,
passed from Python) whose length fixes the dimension: ``load(A, p, eye)``. Compiled code only:
calling these from Python raises.
"""

from __future__ import annotations

from numba import types
from numba.extending import overload

from .tensors import det2, det3, load2, load3, mul2, mul2_bt, mul3, mul3_bt, store2, store3

EYE2 = (1.0, 0.0, 0.0, 1.0)
EYE3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
EYE = {2: EYE2, 3: EYE3}


def _size(a) -> int:
    """4 or 9 for a homogeneous float tuple type, else 0."""
    if isinstance(a, types.UniTuple) and isinstance(a.dtype, types.Float):
        return a.count
    return 0


def _stub(name: str):
    """A distinct Python function per helper: numba attaches each overload to its object."""
    def helper(*args):
        raise NotImplementedError(f"{name}: numba-only helper (hpcmpm.materials.matrix)")
    helper.__name__ = helper.__qualname__ = name
    return helper


load, store, add, sub, scale, axpy = map(_stub, ("load", "store", "add", "sub", "scale", "axpy"))
mul, mul_bt, mul_at, transpose = map(_stub, ("mul", "mul_bt", "mul_at", "transpose"))
trace, det, inverse, cofactor, dcofactor = map(
    _stub, ("trace", "det", "inverse", "cofactor", "dcofactor"))
ddot, eye_like, add_identity, sym, dim_of, root_d = map(
    _stub, ("ddot", "eye_like", "add_identity", "sym", "dim_of", "root_d"))


@overload(load)
def _load(A, p, like):
    """A[p] of an (n, d, d) array as a tuple; ``like`` (EYE2/EYE3) fixes d."""
    if _size(like) == 4:
        return lambda A, p, like: load2(A, p)
    if _size(like) == 9:
        return lambda A, p, like: load3(A, p)


@overload(store)
def _store(A, p, a):
    """A[p] = a."""
    if _size(a) == 4:
        return lambda A, p, a: store2(A, p, a)
    if _size(a) == 9:
        return lambda A, p, a: store3(A, p, a)


@overload(dim_of)
def _dim_of(a):
    """The dimension d as a float (2.0 or 3.0)."""
    if _size(a) == 4:
        return lambda a: 2.0
    if _size(a) == 9:
        return lambda a: 3.0


@overload(root_d)
def _root_d(a, x):
    """x^(1/d) for the dimension of a."""
    if _size(a) == 4:
        return lambda a, x: x ** 0.5
    if _size(a) == 9:
        return lambda a, x: x ** (1.0 / 3.0)


@overload(add)
def _add(a, b):
    """a + b."""
    if _size(a) == 4:
        return lambda a, b: (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])
    if _size(a) == 9:
        return lambda a, b: (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4],
                             a[5] + b[5], a[6] + b[6], a[7] + b[7], a[8] + b[8])


@overload(sub)
def _sub(a, b):
    """a - b."""
    if _size(a) == 4:
        return lambda a, b: (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3])
    if _size(a) == 9:
        return lambda a, b: (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4],
                             a[5] - b[5], a[6] - b[6], a[7] - b[7], a[8] - b[8])


@overload(scale)
def _scale(s, a):
    """s a for a scalar s."""
    if _size(a) == 4:
        return lambda s, a: (s * a[0], s * a[1], s * a[2], s * a[3])
    if _size(a) == 9:
        return lambda s, a: (s * a[0], s * a[1], s * a[2], s * a[3], s * a[4], s * a[5],
                             s * a[6], s * a[7], s * a[8])


@overload(axpy)
def _axpy(s, a, b):
    """s a + b."""
    if _size(a) == 4:
        return lambda s, a, b: (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2],
                                s * a[3] + b[3])
    if _size(a) == 9:
        return lambda s, a, b: (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2],
                                s * a[3] + b[3], s * a[4] + b[4], s * a[5] + b[5],
                                s * a[6] + b[6], s * a[7] + b[7], s * a[8] + b[8])


@overload(mul)
def _mul(a, b):
    """a b."""
    if _size(a) == 4:
        return lambda a, b: mul2(a, b)
    if _size(a) == 9:
        return lambda a, b: mul3(a, b)


@overload(mul_bt)
def _mul_bt(a, b):
    """a b^T."""
    if _size(a) == 4:
        return lambda a, b: mul2_bt(a, b)
    if _size(a) == 9:
        return lambda a, b: mul3_bt(a, b)


@overload(transpose)
def _transpose(a):
    """a^T."""
    if _size(a) == 4:
        return lambda a: (a[0], a[2], a[1], a[3])
    if _size(a) == 9:
        return lambda a: (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@overload(mul_at)
def _mul_at(a, b):
    """a^T b."""
    if _size(a) == 4:
        return lambda a, b: mul2((a[0], a[2], a[1], a[3]), b)
    if _size(a) == 9:
        return lambda a, b: mul3((a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]), b)


@overload(trace)
def _trace(a):
    if _size(a) == 4:
        return lambda a: a[0] + a[3]
    if _size(a) == 9:
        return lambda a: a[0] + a[4] + a[8]


@overload(det)
def _det(a):
    if _size(a) == 4:
        return lambda a: det2(a)
    if _size(a) == 9:
        return lambda a: det3(a)


def _cof3(a):
    return (a[4] * a[8] - a[5] * a[7], a[5] * a[6] - a[3] * a[8], a[3] * a[7] - a[4] * a[6],
            a[2] * a[7] - a[1] * a[8], a[0] * a[8] - a[2] * a[6], a[1] * a[6] - a[0] * a[7],
            a[1] * a[5] - a[2] * a[4], a[2] * a[3] - a[0] * a[5], a[0] * a[4] - a[1] * a[3])


@overload(cofactor)
def _cofactor(a):
    """cof a = det(a) a^-T (defined for singular a too)."""
    if _size(a) == 4:
        return lambda a: (a[3], -a[2], -a[1], a[0])
    if _size(a) == 9:
        return _cof3


def _dcof3(a, h):
    # cof is quadratic in 3D: each entry a cross term of two rows, differentiated by product
    # rule (exact, no cancellation).
    return (h[4] * a[8] + a[4] * h[8] - h[5] * a[7] - a[5] * h[7],
            h[5] * a[6] + a[5] * h[6] - h[3] * a[8] - a[3] * h[8],
            h[3] * a[7] + a[3] * h[7] - h[4] * a[6] - a[4] * h[6],
            h[2] * a[7] + a[2] * h[7] - h[1] * a[8] - a[1] * h[8],
            h[0] * a[8] + a[0] * h[8] - h[2] * a[6] - a[2] * h[6],
            h[1] * a[6] + a[1] * h[6] - h[0] * a[7] - a[0] * h[7],
            h[1] * a[5] + a[1] * h[5] - h[2] * a[4] - a[2] * h[4],
            h[2] * a[3] + a[2] * h[3] - h[0] * a[5] - a[0] * h[5],
            h[0] * a[4] + a[0] * h[4] - h[1] * a[3] - a[1] * h[3])


@overload(dcofactor)
def _dcofactor(a, h):
    """D cof(a)[h], the derivative of the cofactor matrix in direction h (2D: cof is linear)."""
    if _size(a) == 4:
        return lambda a, h: (h[3], -h[2], -h[1], h[0])
    if _size(a) == 9:
        return _dcof3


@overload(inverse)
def _inverse(a):
    """a^-1 = cof(a)^T / det a (inf/nan when a is singular: callers check det first)."""
    if _size(a) == 4:
        def inv2(a):
            r = 1.0 / (a[0] * a[3] - a[1] * a[2])
            return (r * a[3], -r * a[1], -r * a[2], r * a[0])
        return inv2
    if _size(a) == 9:
        def inv3(a):
            c = cofactor(a)
            r = 1.0 / (a[0] * c[0] + a[1] * c[1] + a[2] * c[2])
            return (r * c[0], r * c[3], r * c[6], r * c[1], r * c[4], r * c[7],
                    r * c[2], r * c[5], r * c[8])
        return inv3


@overload(ddot)
def _ddot(a, b):
    """a : b = sum_ij a_ij b_ij."""
    if _size(a) == 4:
        return lambda a, b: a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    if _size(a) == 9:
        return lambda a, b: (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
                             + a[4] * b[4] + a[5] * b[5] + a[6] * b[6] + a[7] * b[7]
                             + a[8] * b[8])


@overload(eye_like)
def _eye_like(a):
    """The identity of a's size."""
    if _size(a) == 4:
        return lambda a: (1.0, 0.0, 0.0, 1.0)
    if _size(a) == 9:
        return lambda a: (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@overload(add_identity)
def _add_identity(a, s):
    """a + s I."""
    if _size(a) == 4:
        return lambda a, s: (a[0] + s, a[1], a[2], a[3] + s)
    if _size(a) == 9:
        return lambda a, s: (a[0] + s, a[1], a[2], a[3], a[4] + s, a[5], a[6], a[7], a[8] + s)


@overload(sym)
def _sym(a):
    """(a + a^T) / 2, exactly symmetric."""
    if _size(a) == 4:
        def sym2(a):
            o = 0.5 * (a[1] + a[2])
            return (a[0], o, o, a[3])
        return sym2
    if _size(a) == 9:
        def sym3(a):
            o01 = 0.5 * (a[1] + a[3])
            o02 = 0.5 * (a[2] + a[6])
            o12 = 0.5 * (a[5] + a[7])
            return (a[0], o01, o02, o01, a[4], o12, o02, o12, a[8])
        return sym3

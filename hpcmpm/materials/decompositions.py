"""Polar decomposition and signed SVD of 2x2 and 3x3 matrices, written with scalars.

Used by the corotated models (R of F = R S) and by snow plasticity (singular-value clamp,
Stomakhin 2013 §5; 000 §4.4; 003 §3.4). The per-particle routines take and return tuples of
scalars (layout of `hpcmpm.materials.tensors`), so they allocate nothing.

The SVD is *signed* (Irving et al. 2004, the convention of Stomakhin 2012): U and V are proper
rotations and only the smallest singular value carries the sign of det F. Then R = U V^T is a
rotation for every F, and F = R S with S = V Sigma V^T.

2D: closed form. R is the rotation by atan2(F10 - F01, F00 + F11) (it maximises tr(R^T F)),
S = R^T F is symmetric, and one Jacobi rotation diagonalises S.

3D: one-sided Jacobi (Hestenes) SVD. Plane rotations applied to the columns of F (and
accumulated into V) until every pair of columns is orthogonal to round-off; the column norms
are then the singular values. Unlike eigen-decomposing F^T F, it keeps small singular values
to full relative accuracy (no squaring of the condition number), it is exact for repeated
singular values (nothing to rotate), and it cannot divide by a vanishing singular value: U is
completed with cross products when columns vanish. The 3D polar decomposition, which only
needs R, first tries Higham's scaled Newton iteration (about 150 ns against 430 ns for the
Jacobi SVD) and falls back to the SVD for nearly singular or inverted F.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .tensors import det3, frob3, mul3, mul3_bt

# Stop rotating a pair of columns once |x.y| <= ORTHO_TOL |x||y|: a few ulps, so the columns
# (hence U) are orthogonal to round-off. Quadratic convergence reaches it in ~4-6 sweeps.
ORTHO_TOL = 4.0e-16
ORTHO_TOL2 = ORTHO_TOL * ORTHO_TOL
MAX_SWEEPS = 30
# Newton polar fast path: used while det F > NEWTON_MIN_DET |F|_F^3 (condition number below
# ~1e4, far beyond any healthy MPM F); the last step is below sqrt(NEWTON_STEP_TOL2) ~ 1e-9,
# so the result is exact to round-off (quadratic convergence).
NEWTON_MIN_DET = 1.0e-9
NEWTON_STEP_TOL2 = 1.0e-18
NEWTON_MAX_ITER = 20


# -- 2D --------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def polar2(f):
    """F = R S for a 2x2 tuple f: returns (R, S) as tuples; S symmetric (SPD when det F > 0)."""
    x = f[0] + f[3]
    y = f[2] - f[1]
    # sqrt and one reciprocal, not hypot and two divisions: hypot is a libm call that took
    # half the 2D corotated stress time; |F| near 1e154 (where x*x overflows) is far past
    # anything the instability guard lets through.
    r = math.sqrt(x * x + y * y)
    if r > 0.0:
        inv_r = 1.0 / r
        c = x * inv_r
        s = y * inv_r
    else:  # F = [[a, b], [b, -a]]: every rotation is as good; take the identity
        c = 1.0
        s = 0.0
    S00 = c * f[0] + s * f[2]
    S11 = -s * f[1] + c * f[3]
    # R^T F is symmetric by construction of the angle; average the two off-diagonal
    # evaluations so S is symmetric to the last bit.
    S01 = 0.5 * ((c * f[1] + s * f[3]) + (-s * f[0] + c * f[2]))
    return (c, -s, s, c), (S00, S01, S01, S11)


@njit(cache=True)
def jacobi_angle(app, aqq, apq):
    """(c, s) of the rotation that zeroes apq of a symmetric 2x2 [[app, apq], [apq, aqq]],
    and t = s / c (Numerical Recipes §11.1, the smaller of the two angles)."""
    if apq == 0.0:
        return 1.0, 0.0, 0.0
    zeta = (aqq - app) / (2.0 * apq)
    if abs(zeta) > 1.0e150:  # zeta^2 would overflow; t -> 1 / (2 zeta)
        t = 0.5 / zeta
    else:
        t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
    c = 1.0 / math.sqrt(1.0 + t * t)
    return c, c * t, t


@njit(cache=True)
def svd2(f):
    """Signed SVD F = U diag(s0, s1) V^T of a 2x2 tuple: returns (U, s0, s1, V), U and V
    rotations (det +1). Not sorted: when det F < 0 the value of smaller magnitude is the
    negative one, s0 or s1."""
    R, S = polar2(f)
    c, s, t = jacobi_angle(S[0], S[3], S[1])
    s0 = S[0] - t * S[1]
    s1 = S[3] + t * S[1]
    V = (c, s, -s, c)
    U = (R[0] * c - R[1] * s, R[0] * s + R[1] * c,
         R[2] * c - R[3] * s, R[2] * s + R[3] * c)
    return U, s0, s1, V


# -- 3D --------------------------------------------------------------------------------------
@njit(cache=True)
def _column_rotation(x0, x1, x2, y0, y1, y2):
    """(c, s) of the plane rotation x' = c x - s y, y' = s x + c y that makes x'.y' = 0;
    (1, 0) when x and y are already orthogonal to ORTHO_TOL."""
    alpha = x0 * x0 + x1 * x1 + x2 * x2
    beta = y0 * y0 + y1 * y1 + y2 * y2
    gamma = x0 * y0 + x1 * y1 + x2 * y2
    # Squared test (no square roots): this runs for every pair of every sweep.
    if gamma * gamma <= ORTHO_TOL2 * alpha * beta:
        return 1.0, 0.0
    c, s, _ = jacobi_angle(alpha, beta, gamma)
    return c, s


@njit(cache=True)
def _rotate(c, s, x0, x1, x2, y0, y1, y2):
    return (c * x0 - s * y0, c * x1 - s * y1, c * x2 - s * y2,
            s * x0 + c * y0, s * x1 + c * y1, s * x2 + c * y2)


@njit(cache=True)
def _unit_orthogonal(x0, x1, x2):
    """A unit vector orthogonal to the unit vector x (cross x with its least aligned axis)."""
    ax, ay, az = abs(x0), abs(x1), abs(x2)
    if ax <= ay and ax <= az:  # e0 x x
        w0, w1, w2 = 0.0, -x2, x1
    elif ay <= az:  # e1 x x
        w0, w1, w2 = x2, 0.0, -x0
    else:  # e2 x x
        w0, w1, w2 = -x1, x0, 0.0
    n = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    return w0 / n, w1 / n, w2 / n


@njit(cache=True)
def svd3(f):
    """Signed SVD F = U diag(s0, s1, s2) V^T of a 3x3 row-major tuple: returns
    (U, s0, s1, s2, V) with U, V rotations (det +1), s0 >= s1 >= |s2|, s2 < 0 iff det F < 0."""
    # Columns a, b, c of F V; V starts at I and collects the same rotations.
    a0, a1, a2 = f[0], f[3], f[6]
    b0, b1, b2 = f[1], f[4], f[7]
    c0, c1, c2 = f[2], f[5], f[8]
    va0, va1, va2 = 1.0, 0.0, 0.0
    vb0, vb1, vb2 = 0.0, 1.0, 0.0
    vc0, vc1, vc2 = 0.0, 0.0, 1.0
    for _ in range(MAX_SWEEPS):
        rotated = False
        co, si = _column_rotation(a0, a1, a2, b0, b1, b2)
        if si != 0.0:
            rotated = True
            a0, a1, a2, b0, b1, b2 = _rotate(co, si, a0, a1, a2, b0, b1, b2)
            va0, va1, va2, vb0, vb1, vb2 = _rotate(co, si, va0, va1, va2, vb0, vb1, vb2)
        co, si = _column_rotation(a0, a1, a2, c0, c1, c2)
        if si != 0.0:
            rotated = True
            a0, a1, a2, c0, c1, c2 = _rotate(co, si, a0, a1, a2, c0, c1, c2)
            va0, va1, va2, vc0, vc1, vc2 = _rotate(co, si, va0, va1, va2, vc0, vc1, vc2)
        co, si = _column_rotation(b0, b1, b2, c0, c1, c2)
        if si != 0.0:
            rotated = True
            b0, b1, b2, c0, c1, c2 = _rotate(co, si, b0, b1, b2, c0, c1, c2)
            vb0, vb1, vb2, vc0, vc1, vc2 = _rotate(co, si, vb0, vb1, vb2, vc0, vc1, vc2)
        if not rotated:
            break
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    nc = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    # Sort columns by norm, descending (swapping two columns of V and F V together keeps
    # F V = columns; the sign of det V is fixed below).
    if na < nb:
        na, nb = nb, na
        a0, a1, a2, b0, b1, b2 = b0, b1, b2, a0, a1, a2
        va0, va1, va2, vb0, vb1, vb2 = vb0, vb1, vb2, va0, va1, va2
    if na < nc:
        na, nc = nc, na
        a0, a1, a2, c0, c1, c2 = c0, c1, c2, a0, a1, a2
        va0, va1, va2, vc0, vc1, vc2 = vc0, vc1, vc2, va0, va1, va2
    if nb < nc:
        nb, nc = nc, nb
        b0, b1, b2, c0, c1, c2 = c0, c1, c2, b0, b1, b2
        vb0, vb1, vb2, vc0, vc1, vc2 = vc0, vc1, vc2, vb0, vb1, vb2
    # Make V a rotation: flipping its last column flips the last column of F V too.
    det_v = (va0 * (vb1 * vc2 - vb2 * vc1) - vb0 * (va1 * vc2 - va2 * vc1)
             + vc0 * (va1 * vb2 - va2 * vb1))
    if det_v < 0.0:
        vc0, vc1, vc2 = -vc0, -vc1, -vc2
        c0, c1, c2 = -c0, -c1, -c2
    # U: normalised columns; a vanishing column gets any orthogonal direction, and the third
    # is always the cross product so U is a rotation and s2 carries the sign of det F.
    if na > 0.0:
        u00, u10, u20 = a0 / na, a1 / na, a2 / na
    else:
        u00, u10, u20 = 1.0, 0.0, 0.0
    if nb > 0.0:
        w0, w1, w2 = b0 / nb, b1 / nb, b2 / nb
        # Re-orthogonalise against u0: cheap insurance when nb is tiny next to na.
        d = w0 * u00 + w1 * u10 + w2 * u20
        w0, w1, w2 = w0 - d * u00, w1 - d * u10, w2 - d * u20
        nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        if nw > 0.5:
            u01, u11, u21 = w0 / nw, w1 / nw, w2 / nw
        else:
            u01, u11, u21 = _unit_orthogonal(u00, u10, u20)
    else:
        u01, u11, u21 = _unit_orthogonal(u00, u10, u20)
    u02 = u10 * u21 - u20 * u11
    u12 = u20 * u01 - u00 * u21
    u22 = u00 * u11 - u10 * u01
    s2 = u02 * c0 + u12 * c1 + u22 * c2
    U = (u00, u01, u02, u10, u11, u12, u20, u21, u22)
    V = (va0, vb0, vc0, va1, vb1, vc1, va2, vb2, vc2)
    return U, na, nb, s2, V


@njit(cache=True)
def _newton_rotation3(f):
    """Rotation of F = R S by Higham's scaled Newton iteration X <- (g X + X^-T / g) / 2
    (Higham 1986, Frobenius-norm scaling g). Returns (R, True), or (F, False) when F is too
    ill conditioned for it (det F <= NEWTON_MIN_DET |F|^3) or it does not converge."""
    x = f
    norm2 = frob3(x)
    if not det3(x) > NEWTON_MIN_DET * norm2 * math.sqrt(norm2):
        return f, False
    for _ in range(NEWTON_MAX_ITER):
        c = (x[4] * x[8] - x[5] * x[7], x[5] * x[6] - x[3] * x[8], x[3] * x[7] - x[4] * x[6],
             x[2] * x[7] - x[1] * x[8], x[0] * x[8] - x[2] * x[6], x[1] * x[6] - x[0] * x[7],
             x[1] * x[5] - x[2] * x[4], x[2] * x[3] - x[0] * x[5], x[0] * x[4] - x[1] * x[3])
        det = x[0] * c[0] + x[1] * c[1] + x[2] * c[2]
        if not det > 0.0:
            return f, False
        # X^-T = cof(X) / det; g = sqrt(|X^-1| / |X|) balances the two terms.
        g = math.sqrt(math.sqrt(frob3(c)) / (det * math.sqrt(frob3(x))))
        a = 0.5 * g
        b = 0.5 / (g * det)
        y = (a * x[0] + b * c[0], a * x[1] + b * c[1], a * x[2] + b * c[2],
             a * x[3] + b * c[3], a * x[4] + b * c[4], a * x[5] + b * c[5],
             a * x[6] + b * c[6], a * x[7] + b * c[7], a * x[8] + b * c[8])
        change = 0.0
        for k in range(9):
            change += (y[k] - x[k]) * (y[k] - x[k])
        x = y
        # Quadratic convergence: a step of size e leaves an error ~e^2, so stop one step
        # after the step drops below sqrt(eps).
        if change < NEWTON_STEP_TOL2:
            return x, True
    return f, False


@njit(cache=True)
def polar3(f):
    """F = R S for a 3x3 tuple: returns (R, S), R a rotation, S = R^T F symmetric.

    Well-conditioned F (every F of a healthy MPM step) takes the scaled Newton iteration, about
    4x cheaper than the Jacobi SVD; nearly singular or inverted F falls back to the signed SVD
    (R = U V^T, S = V Sigma V^T)."""
    R, ok = _newton_rotation3(f)
    if ok:
        S = mul3(_transpose3(R), f)
        return R, _symmetrize3(S)
    U, s0, s1, s2, V = svd3(f)
    return mul3_bt(U, V), v_diag_vt(V, s0, s1, s2)


@njit(cache=True)
def _transpose3(a):
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit(cache=True)
def _symmetrize3(a):
    s01 = 0.5 * (a[1] + a[3])
    s02 = 0.5 * (a[2] + a[6])
    s12 = 0.5 * (a[5] + a[7])
    return (a[0], s01, s02, s01, a[4], s12, s02, s12, a[8])


@njit(cache=True)
def v_diag_vt(V, s0, s1, s2):
    """V diag(s) V^T (symmetric; the upper triangle is mirrored so it is exactly so)."""
    S00 = V[0] * V[0] * s0 + V[1] * V[1] * s1 + V[2] * V[2] * s2
    S01 = V[0] * V[3] * s0 + V[1] * V[4] * s1 + V[2] * V[5] * s2
    S02 = V[0] * V[6] * s0 + V[1] * V[7] * s1 + V[2] * V[8] * s2
    S11 = V[3] * V[3] * s0 + V[4] * V[4] * s1 + V[5] * V[5] * s2
    S12 = V[3] * V[6] * s0 + V[4] * V[7] * s1 + V[5] * V[8] * s2
    S22 = V[6] * V[6] * s0 + V[7] * V[7] * s1 + V[8] * V[8] * s2
    return (S00, S01, S02, S01, S11, S12, S02, S12, S22)


# -- batched, for tests and diagnostics ------------------------------------------------------
@njit(cache=True)
def _polar_batch(F, R, S):
    n, d = F.shape[0], F.shape[1]
    for p in range(n):
        if d == 2:
            f = (F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1])
            r, s = polar2(f)
            for k in range(4):
                R[p, k // 2, k % 2] = r[k]
                S[p, k // 2, k % 2] = s[k]
        else:
            f = (F[p, 0, 0], F[p, 0, 1], F[p, 0, 2], F[p, 1, 0], F[p, 1, 1], F[p, 1, 2],
                 F[p, 2, 0], F[p, 2, 1], F[p, 2, 2])
            r3, s3 = polar3(f)
            for k in range(9):
                R[p, k // 3, k % 3] = r3[k]
                S[p, k // 3, k % 3] = s3[k]


@njit(cache=True)
def _svd_batch(F, U, sigma, V):
    n, d = F.shape[0], F.shape[1]
    for p in range(n):
        if d == 2:
            f = (F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1])
            u, s0, s1, v = svd2(f)
            sigma[p, 0] = s0
            sigma[p, 1] = s1
            for k in range(4):
                U[p, k // 2, k % 2] = u[k]
                V[p, k // 2, k % 2] = v[k]
        else:
            f = (F[p, 0, 0], F[p, 0, 1], F[p, 0, 2], F[p, 1, 0], F[p, 1, 1], F[p, 1, 2],
                 F[p, 2, 0], F[p, 2, 1], F[p, 2, 2])
            u3, t0, t1, t2, v3 = svd3(f)
            sigma[p, 0] = t0
            sigma[p, 1] = t1
            sigma[p, 2] = t2
            for k in range(9):
                U[p, k // 3, k % 3] = u3[k]
                V[p, k // 3, k % 3] = v3[k]


def polar(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar decomposition of a batch: F (n, d, d) -> (R, S), each (n, d, d), F = R S."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    R = np.empty_like(F)
    S = np.empty_like(F)
    _polar_batch(F, R, S)
    return R, S


def svd(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed SVD of a batch: F (n, d, d) -> U (n, d, d), sigma (n, d), V (n, d, d),
    F = U diag(sigma) V^T with U, V rotations."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    U = np.empty_like(F)
    V = np.empty_like(F)
    sigma = np.empty(F.shape[:2], dtype=np.float64)
    _svd_batch(F, U, sigma, V)
    return U, sigma, V

"""What G2P does with the step's velocity gradient: advance F, advance J, or store L.

Most materials need F. Volumetric ones (the weakly compressible fluid) need only J = det F, so
a scene made of them stores J (8 B per particle instead of 32 in 2D, 72 in 3D) and G2P
advances it with ``J <- det(I + dt grad v) J``, the determinant of the F update
``F <- (I + dt grad v) F`` (000 eq. 3.7): the same J to round-off, at a quarter of the cost.
Rate-dependent and plastic models (Oldroyd-B, Herschel-Bulkley, J2) integrate their own
state over the step from the velocity gradient itself: G2P then stores ``L_p = grad v_p``
(the field ``L``) and each material advances its state in ``update_state``.

The kernels are written once and call these helpers; numba picks the implementation from
the argument's type when it compiles the caller (an (n,) array is J, an (n, d, d) array F,
a 1-tuple ``(L,)`` of an (n, d, d) array means "store L"), so no kernel carries a branch for
the others.
"""

from __future__ import annotations

from numba import njit, types
from numba.extending import overload


def advance_2d(F, p, dt, g00, g01, g10, g11):
    """``F[p] <- (I + dt g) F[p]`` for (n, 2, 2) F, or ``F[p] <- det(I + dt g) F[p]`` for
    (n,) J. Compiled code only."""
    raise NotImplementedError("numba-only helper")


def advance_3d(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22):
    """3D version of `advance_2d`. Compiled code only."""
    raise NotImplementedError("numba-only helper")


def volume_ratio(F, p):
    """det F[p] for (n, d, d) F, or J[p] for (n,) J. Compiled code only."""
    raise NotImplementedError("numba-only helper")


@overload(advance_2d, inline="always")
def _advance_2d(F, p, dt, g00, g01, g10, g11):
    if isinstance(F, types.UniTuple):
        def store_L(F, p, dt, g00, g01, g10, g11):
            L = F[0]
            L[p, 0, 0], L[p, 0, 1], L[p, 1, 0], L[p, 1, 1] = g00, g01, g10, g11
        return store_L
    if isinstance(F, types.Array) and F.ndim == 1:
        def advance_J(F, p, dt, g00, g01, g10, g11):
            F[p] *= (1.0 + dt * g00) * (1.0 + dt * g11) - dt * dt * g01 * g10
        return advance_J

    def advance_F(F, p, dt, g00, g01, g10, g11):
        f00, f01, f10, f11 = F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1]
        F[p, 0, 0] = f00 + dt * (g00 * f00 + g01 * f10)
        F[p, 0, 1] = f01 + dt * (g00 * f01 + g01 * f11)
        F[p, 1, 0] = f10 + dt * (g10 * f00 + g11 * f10)
        F[p, 1, 1] = f11 + dt * (g10 * f01 + g11 * f11)
    return advance_F


@overload(advance_3d, inline="always")
def _advance_3d(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22):
    if isinstance(F, types.UniTuple):
        def store_L(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22):
            L = F[0]
            L[p, 0, 0], L[p, 0, 1], L[p, 0, 2] = g00, g01, g02
            L[p, 1, 0], L[p, 1, 1], L[p, 1, 2] = g10, g11, g12
            L[p, 2, 0], L[p, 2, 1], L[p, 2, 2] = g20, g21, g22
        return store_L
    if isinstance(F, types.Array) and F.ndim == 1:
        def advance_J(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22):
            a00, a01, a02 = 1.0 + dt * g00, dt * g01, dt * g02
            a10, a11, a12 = dt * g10, 1.0 + dt * g11, dt * g12
            a20, a21, a22 = dt * g20, dt * g21, 1.0 + dt * g22
            F[p] *= (a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20)
                     + a02 * (a10 * a21 - a11 * a20))
        return advance_J

    def advance_F(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22):
        for c in range(3):
            f0, f1, f2 = F[p, 0, c], F[p, 1, c], F[p, 2, c]
            F[p, 0, c] = f0 + dt * (g00 * f0 + g01 * f1 + g02 * f2)
            F[p, 1, c] = f1 + dt * (g10 * f0 + g11 * f1 + g12 * f2)
            F[p, 2, c] = f2 + dt * (g20 * f0 + g21 * f1 + g22 * f2)
    return advance_F


@overload(volume_ratio, inline="always")
def _volume_ratio(F, p):
    if isinstance(F, types.Array) and F.ndim == 1:
        return lambda F, p: F[p]
    if isinstance(F, types.Array) and F.ndim == 3:
        def det_F(F, p):
            if F.shape[1] == 2:
                return F[p, 0, 0] * F[p, 1, 1] - F[p, 0, 1] * F[p, 1, 0]
            return (F[p, 0, 0] * (F[p, 1, 1] * F[p, 2, 2] - F[p, 1, 2] * F[p, 2, 1])
                    - F[p, 0, 1] * (F[p, 1, 0] * F[p, 2, 2] - F[p, 1, 2] * F[p, 2, 0])
                    + F[p, 0, 2] * (F[p, 1, 0] * F[p, 2, 1] - F[p, 1, 1] * F[p, 2, 0]))
        return det_F
    return None


@njit(cache=True)
def advance_by_velocity_gradient(F, L, dt):
    """``F_p <- (I + dt L_p) F_p`` for (n, d, d) F, or ``J_p <- det(I + dt L_p) J_p`` for (n,)
    J, with L (n, d, d) the step's velocity gradient stored by G2P: exactly what G2P does
    in modes "F" and "J" (000 eq. 3.7), for materials that share a scene with a model that
    needs L."""
    if L.shape[1] == 2:
        for p in range(L.shape[0]):
            advance_2d(F, p, dt, L[p, 0, 0], L[p, 0, 1], L[p, 1, 0], L[p, 1, 1])
    else:
        for p in range(L.shape[0]):
            advance_3d(F, p, dt, L[p, 0, 0], L[p, 0, 1], L[p, 0, 2], L[p, 1, 0], L[p, 1, 1],
                       L[p, 1, 2], L[p, 2, 0], L[p, 2, 1], L[p, 2, 2])

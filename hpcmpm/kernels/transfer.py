"""Particle-to-grid and grid-to-particle transfers: PIC, FLIP/PIC blend, APIC, MLS-MPM.

One scatter and one gather kernel per dimension, compiled once per (scheme, kernel order)
pair: the two are passed through `static`, which makes them compile-time constants.

- PIC / FLIP (000 §3.4): momentum ``w m v``; FLIP blends ``v_p <- alpha (v_p + sum w dv_i)
  + (1 - alpha) sum w v_i``.
- APIC (Jiang 2015 eq. 10-13): momentum ``w m (v_p + C_p (x_i - x_p))``, ``C_p = B_p D^-1``.
- MLS-MPM (Hu 2018 eq. 17-18; 003 §3.2): as APIC, with the stress entering the same affine
  term, ``-dt V0 D^-1 tau (x_i - x_p)``, and ``grad v = C``.

Non-MLS schemes use the gradient form of the internal force (000 eq. 3.1):
``f_i = -sum_p V0_p tau_p grad w_ip`` with tau the Kirchhoff stress, and update
``F <- (I + dt grad v) F`` with ``grad v = sum_i v_i (grad w_ip)^T`` (000 eq. 3.7).

When ``split_force`` (``static(True)`` or ``static(False)``) is true the impulse ``dt f_i`` goes to its own grid array (FLIP needs the
pre-force velocity; an implicit solve needs the force alone); otherwise it is added to the
momentum, which saves one grid write per node.
"""

from __future__ import annotations

from numba import njit

from .deformation import advance_2d, advance_3d
from .shape import node, stencil_base, stencil_weights_2d, stencil_weights_3d, weights

PIC, FLIP, APIC, MLS = 0, 1, 2, 3
SCHEMES = {"pic": PIC, "flip": FLIP, "apic": APIC, "mls": MLS}


def static(value: int) -> tuple:
    """``value`` in a form numba compiles into the kernel: a tuple of that length.

    The kernels take ``scheme`` and ``order`` as ``static(SCHEMES[...])`` and
    ``static(ORDERS[...])`` and read them back with ``len()``. numba compiles one machine-code
    version per argument *type*, and a tuple's length is part of its type, so each
    (scheme, order) pair gets its own version with the stencil loops unrolled and the other
    schemes' branches removed; the on-disk cache keys on the types, so it keeps working
    across processes. (Closures are not cached by numba and ``numba.literally`` re-types on
    every start; both were measured here at 4 s and 18 s of warm start-up.) Specialising made
    the 2D MLS P2G 2.2x and G2P 1.7x faster than with run-time integers."""
    return (0,) * int(value)  # static(True) == (0,), static(False) == ()


@njit(cache=True)
def scatter_2d(x, v, C, mass, vol0, tau, scheme, order, dinv_factor, dx, domain_lo, origin,
               dt, split_force, grid_mass, grid_momentum, grid_impulse):
    """P2G in 2D: mass, momentum and the stress impulse ``dt f`` onto the block.

    x, v (n, 2); C, tau (n, 2, 2) (C unused for PIC/FLIP); mass, vol0 (n,);
    grid_mass (nx, ny); grid_momentum, grid_impulse (nx, ny, 2), accumulated in place."""
    scheme, order = len(scheme), len(order)  # compile-time constants: see `static`
    split_force = len(split_force) > 0
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    affine = scheme >= APIC
    mls = scheme == MLS
    # Loop invariants as scalars: as array reads the compiler reloads them after every
    # particle store, since it cannot prove the arrays do not alias.
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        m = mass[p]
        vd = dt * vol0[p]
        t00, t01, t10, t11 = tau[p, 0, 0], tau[p, 0, 1], tau[p, 1, 0], tau[p, 1, 1]
        mv0, mv1 = m * v[p, 0], m * v[p, 1]
        a00 = a01 = a10 = a11 = 0.0
        if affine:
            a00, a01, a10, a11 = m * C[p, 0, 0], m * C[p, 0, 1], m * C[p, 1, 0], m * C[p, 1, 1]
        # MLS stress as an affine term (Hu 2018 eq. 18); k = -dt V0 D^-1.
        k = -vd * dinv
        s00, s01, s10, s11 = k * t00, k * t01, k * t10, k * t11
        if mls and not split_force:
            a00 += s00
            a01 += s01
            a10 += s10
            a11 += s11
        l0 = node(b0 - o0)
        l1 = node(b1 - o1)
        # x_i - x_p of the stencil's first node; the others are whole cells further.
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        for i in range(node(s)):
            d0 = e0 + i * dx
            for j in range(node(s)):
                d1 = e1 + j * dx
                wij = w0[i] * w1[j]
                n0, n1 = l0 + i, l1 + j
                grid_mass[n0, n1] += wij * m
                grid_momentum[n0, n1, 0] += wij * (mv0 + a00 * d0 + a01 * d1)
                grid_momentum[n0, n1, 1] += wij * (mv1 + a10 * d0 + a11 * d1)
                if mls:
                    if split_force:
                        grid_impulse[n0, n1, 0] += wij * (s00 * d0 + s01 * d1)
                        grid_impulse[n0, n1, 1] += wij * (s10 * d0 + s11 * d1)
                else:
                    g0 = dw0[i] * w1[j]
                    g1 = w0[i] * dw1[j]
                    f0 = -vd * (t00 * g0 + t01 * g1)
                    f1 = -vd * (t10 * g0 + t11 * g1)
                    if split_force:
                        grid_impulse[n0, n1, 0] += f0
                        grid_impulse[n0, n1, 1] += f1
                    else:
                        grid_momentum[n0, n1, 0] += f0
                        grid_momentum[n0, n1, 1] += f1


@njit(cache=True)
def scatter_3d(x, v, C, mass, vol0, tau, scheme, order, dinv_factor, dx, domain_lo, origin,
               dt, split_force, grid_mass, grid_momentum, grid_impulse):
    """P2G in 3D; see `scatter_2d` (same algorithm, arrays with a third axis)."""
    scheme, order = len(scheme), len(order)  # compile-time constants: see `static`
    split_force = len(split_force) > 0
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    affine = scheme >= APIC
    mls = scheme == MLS
    # Loop invariants as scalars: as array reads the compiler reloads them after every
    # particle store, since it cannot prove the arrays do not alias.
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        m = mass[p]
        vd = dt * vol0[p]
        t00, t01, t02 = tau[p, 0, 0], tau[p, 0, 1], tau[p, 0, 2]
        t10, t11, t12 = tau[p, 1, 0], tau[p, 1, 1], tau[p, 1, 2]
        t20, t21, t22 = tau[p, 2, 0], tau[p, 2, 1], tau[p, 2, 2]
        mv0, mv1, mv2 = m * v[p, 0], m * v[p, 1], m * v[p, 2]
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        if affine:
            a00, a01, a02 = m * C[p, 0, 0], m * C[p, 0, 1], m * C[p, 0, 2]
            a10, a11, a12 = m * C[p, 1, 0], m * C[p, 1, 1], m * C[p, 1, 2]
            a20, a21, a22 = m * C[p, 2, 0], m * C[p, 2, 1], m * C[p, 2, 2]
        k = -vd * dinv
        s00, s01, s02 = k * t00, k * t01, k * t02
        s10, s11, s12 = k * t10, k * t11, k * t12
        s20, s21, s22 = k * t20, k * t21, k * t22
        if mls and not split_force:
            a00 += s00
            a01 += s01
            a02 += s02
            a10 += s10
            a11 += s11
            a12 += s12
            a20 += s20
            a21 += s21
            a22 += s22
        l0 = node(b0 - o0)
        l1 = node(b1 - o1)
        l2 = node(b2 - o2)
        # x_i - x_p of the stencil's first node; the others are whole cells further.
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        for i in range(node(s)):
            d0 = e0 + i * dx
            for j in range(node(s)):
                d1 = e1 + j * dx
                wij = w0[i] * w1[j]
                for kk in range(node(s)):
                    d2 = e2 + kk * dx
                    wijk = wij * w2[kk]
                    n0, n1, n2 = l0 + i, l1 + j, l2 + kk
                    grid_mass[n0, n1, n2] += wijk * m
                    grid_momentum[n0, n1, n2, 0] += wijk * (mv0 + a00 * d0 + a01 * d1 + a02 * d2)
                    grid_momentum[n0, n1, n2, 1] += wijk * (mv1 + a10 * d0 + a11 * d1 + a12 * d2)
                    grid_momentum[n0, n1, n2, 2] += wijk * (mv2 + a20 * d0 + a21 * d1 + a22 * d2)
                    if mls:
                        if split_force:
                            grid_impulse[n0, n1, n2, 0] += wijk * (s00 * d0 + s01 * d1 + s02 * d2)
                            grid_impulse[n0, n1, n2, 1] += wijk * (s10 * d0 + s11 * d1 + s12 * d2)
                            grid_impulse[n0, n1, n2, 2] += wijk * (s20 * d0 + s21 * d1 + s22 * d2)
                    else:
                        g0 = dw0[i] * w1[j] * w2[kk]
                        g1 = w0[i] * dw1[j] * w2[kk]
                        g2 = wij * dw2[kk]
                        f0 = -vd * (t00 * g0 + t01 * g1 + t02 * g2)
                        f1 = -vd * (t10 * g0 + t11 * g1 + t12 * g2)
                        f2 = -vd * (t20 * g0 + t21 * g1 + t22 * g2)
                        if split_force:
                            grid_impulse[n0, n1, n2, 0] += f0
                            grid_impulse[n0, n1, n2, 1] += f1
                            grid_impulse[n0, n1, n2, 2] += f2
                        else:
                            grid_momentum[n0, n1, n2, 0] += f0
                            grid_momentum[n0, n1, n2, 1] += f1
                            grid_momentum[n0, n1, n2, 2] += f2


@njit(cache=True)
def gather_2d(x, v, C, F, scheme, order, dinv_factor, dx, domain_lo, origin, dt, flip_alpha,
              grid_velocity, grid_velocity_old):
    """G2P in 2D: new v (and C), F <- (I + dt grad v) F, x <- x + dt v_pic. In place.

    F is (n, 2, 2), or the (n,) volume ratio J of a scene of volumetric materials
    (`hpcmpm.kernels.deformation`).

    grid_velocity_old is read only for FLIP."""
    scheme, order = len(scheme), len(order)  # compile-time constants: see `static`
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    affine = scheme >= APIC
    # Loop invariants as scalars: as array reads the compiler reloads them after every
    # particle store, since it cannot prove the arrays do not alias.
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        l0 = node(b0 - o0)
        l1 = node(b1 - o1)
        # x_i - x_p of the stencil's first node; the others are whole cells further.
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        u0 = u1 = 0.0
        du0 = du1 = 0.0
        b00 = b01 = b10 = b11 = 0.0
        g00 = g01 = g10 = g11 = 0.0
        for i in range(node(s)):
            d0 = e0 + i * dx
            for j in range(node(s)):
                d1 = e1 + j * dx
                wij = w0[i] * w1[j]
                n0, n1 = l0 + i, l1 + j
                vi0 = grid_velocity[n0, n1, 0]
                vi1 = grid_velocity[n0, n1, 1]
                u0 += wij * vi0
                u1 += wij * vi1
                if affine:
                    b00 += wij * vi0 * d0
                    b01 += wij * vi0 * d1
                    b10 += wij * vi1 * d0
                    b11 += wij * vi1 * d1
                if scheme != MLS:
                    gw0 = dw0[i] * w1[j]
                    gw1 = w0[i] * dw1[j]
                    g00 += vi0 * gw0
                    g01 += vi0 * gw1
                    g10 += vi1 * gw0
                    g11 += vi1 * gw1
                if scheme == FLIP:
                    du0 += wij * (vi0 - grid_velocity_old[n0, n1, 0])
                    du1 += wij * (vi1 - grid_velocity_old[n0, n1, 1])
        if affine:
            b00 *= dinv
            b01 *= dinv
            b10 *= dinv
            b11 *= dinv
            C[p, 0, 0], C[p, 0, 1], C[p, 1, 0], C[p, 1, 1] = b00, b01, b10, b11
        if scheme == MLS:
            g00, g01, g10, g11 = b00, b01, b10, b11
        if scheme == FLIP:
            v[p, 0] = flip_alpha * (v[p, 0] + du0) + (1.0 - flip_alpha) * u0
            v[p, 1] = flip_alpha * (v[p, 1] + du1) + (1.0 - flip_alpha) * u1
        else:
            v[p, 0] = u0
            v[p, 1] = u1
        x[p, 0] += dt * u0
        x[p, 1] += dt * u1
        advance_2d(F, p, dt, g00, g01, g10, g11)


@njit(cache=True)
def gather_3d(x, v, C, F, scheme, order, dinv_factor, dx, domain_lo, origin, dt, flip_alpha,
              grid_velocity, grid_velocity_old):
    """G2P in 3D; see `gather_2d`. The 3x3 accumulators are scalars so they stay in
    registers (small arrays here cost about 30% of the kernel)."""
    scheme, order = len(scheme), len(order)  # compile-time constants: see `static`
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    affine = scheme >= APIC
    # Loop invariants as scalars: as array reads the compiler reloads them after every
    # particle store, since it cannot prove the arrays do not alias.
    lo0, lo1, lo2 = domain_lo[0], domain_lo[1], domain_lo[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - lo1) * inv_dx
        xi2 = (x[p, 2] - lo2) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        w0, dw0 = weights(xi0, b0, order, inv_dx)
        w1, dw1 = weights(xi1, b1, order, inv_dx)
        w2, dw2 = weights(xi2, b2, order, inv_dx)
        l0 = node(b0 - o0)
        l1 = node(b1 - o1)
        l2 = node(b2 - o2)
        # x_i - x_p of the stencil's first node; the others are whole cells further.
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        u0 = u1 = u2 = 0.0
        du0 = du1 = du2 = 0.0
        c00 = c01 = c02 = c10 = c11 = c12 = c20 = c21 = c22 = 0.0
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        for i in range(node(s)):
            d0 = e0 + i * dx
            for j in range(node(s)):
                d1 = e1 + j * dx
                wij = w0[i] * w1[j]
                for kk in range(node(s)):
                    d2 = e2 + kk * dx
                    wijk = wij * w2[kk]
                    n0, n1, n2 = l0 + i, l1 + j, l2 + kk
                    vi0 = grid_velocity[n0, n1, n2, 0]
                    vi1 = grid_velocity[n0, n1, n2, 1]
                    vi2 = grid_velocity[n0, n1, n2, 2]
                    u0 += wijk * vi0
                    u1 += wijk * vi1
                    u2 += wijk * vi2
                    if affine:
                        wv0, wv1, wv2 = wijk * vi0, wijk * vi1, wijk * vi2
                        c00 += wv0 * d0
                        c01 += wv0 * d1
                        c02 += wv0 * d2
                        c10 += wv1 * d0
                        c11 += wv1 * d1
                        c12 += wv1 * d2
                        c20 += wv2 * d0
                        c21 += wv2 * d1
                        c22 += wv2 * d2
                    if scheme != MLS:
                        gw0 = dw0[i] * w1[j] * w2[kk]
                        gw1 = w0[i] * dw1[j] * w2[kk]
                        gw2 = wij * dw2[kk]
                        g00 += vi0 * gw0
                        g01 += vi0 * gw1
                        g02 += vi0 * gw2
                        g10 += vi1 * gw0
                        g11 += vi1 * gw1
                        g12 += vi1 * gw2
                        g20 += vi2 * gw0
                        g21 += vi2 * gw1
                        g22 += vi2 * gw2
                    if scheme == FLIP:
                        du0 += wijk * (vi0 - grid_velocity_old[n0, n1, n2, 0])
                        du1 += wijk * (vi1 - grid_velocity_old[n0, n1, n2, 1])
                        du2 += wijk * (vi2 - grid_velocity_old[n0, n1, n2, 2])
        if affine:
            c00 *= dinv
            c01 *= dinv
            c02 *= dinv
            c10 *= dinv
            c11 *= dinv
            c12 *= dinv
            c20 *= dinv
            c21 *= dinv
            c22 *= dinv
            C[p, 0, 0], C[p, 0, 1], C[p, 0, 2] = c00, c01, c02
            C[p, 1, 0], C[p, 1, 1], C[p, 1, 2] = c10, c11, c12
            C[p, 2, 0], C[p, 2, 1], C[p, 2, 2] = c20, c21, c22
        if scheme == MLS:
            g00, g01, g02, g10, g11, g12, g20, g21, g22 = (
                c00, c01, c02, c10, c11, c12, c20, c21, c22)
        if scheme == FLIP:
            v[p, 0] = flip_alpha * (v[p, 0] + du0) + (1.0 - flip_alpha) * u0
            v[p, 1] = flip_alpha * (v[p, 1] + du1) + (1.0 - flip_alpha) * u1
            v[p, 2] = flip_alpha * (v[p, 2] + du2) + (1.0 - flip_alpha) * u2
        else:
            v[p, 0] = u0
            v[p, 1] = u1
            v[p, 2] = u2
        x[p, 0] += dt * u0
        x[p, 1] += dt * u1
        x[p, 2] += dt * u2
        advance_3d(F, p, dt, g00, g01, g02, g10, g11, g12, g20, g21, g22)


@njit(cache=True)
def scatter_forces_2d(x, f, order, dx, domain_lo, origin, dt, grid_momentum):
    """The force channel in 2D: ``dt sum_p w_ip f_p`` onto the block's momentum (or impulse).

    x, f (n, 2): positions and forces (force units, e.g. the peridynamic bond force of
    integral-based MPM, 003 eq. 5.2 corrected: f_i = sum_p w_ip f_p)."""
    order = len(order)  # compile-time constant: see `static`
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, l0, l1 = stencil_weights_2d(x, p, order, inv_dx, domain_lo, origin)
        f0, f1 = dt * f[p, 0], dt * f[p, 1]
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                grid_momentum[l0 + i, l1 + j, 0] += wij * f0
                grid_momentum[l0 + i, l1 + j, 1] += wij * f1


@njit(cache=True)
def scatter_forces_3d(x, f, order, dx, domain_lo, origin, dt, grid_momentum):
    """The force channel in 3D; see `scatter_forces_2d`."""
    order = len(order)  # compile-time constant: see `static`
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        w0, w1, w2, l0, l1, l2 = stencil_weights_3d(x, p, order, inv_dx, domain_lo, origin)
        f0, f1, f2 = dt * f[p, 0], dt * f[p, 1], dt * f[p, 2]
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j]
                for k in range(node(s)):
                    w = wij * w2[k]
                    grid_momentum[l0 + i, l1 + j, l2 + k, 0] += w * f0
                    grid_momentum[l0 + i, l1 + j, l2 + k, 1] += w * f1
                    grid_momentum[l0 + i, l1 + j, l2 + k, 2] += w * f2


SCATTER = {2: scatter_2d, 3: scatter_3d}
SCATTER_FORCES = {2: scatter_forces_2d, 3: scatter_forces_3d}
GATHER = {2: gather_2d, 3: gather_3d}

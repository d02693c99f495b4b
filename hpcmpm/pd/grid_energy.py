"""Eigenerosion energy on the grid (003 eq. 6.10, as corrected in issue 11) and the EE flags.

Per particle, from its Cauchy stress sigma = tau / det F:

    sigma+ = sum_k max(sigma_k, 0) n_k (x) n_k        tensile part (eigenpairs sigma_k, n_k)
    Phi    = sigma+ : sigma+                          energy = "stress_squared" (as printed)
    Phi    = ((1 + nu) sigma+:sigma+ - nu (tr sigma+)^2) / (2 E)
                                                      energy = "tensile_energy" (J/m^3, so
                                                      G is in J/m^2 as in Pandolfi & Ortiz 2012)
    EE_p   = max(EE_p, Phi)                           history (Wolper 2019), never decreases

and on the grid one extra scattered field, summed to owners like the mass,

    e_i = sum_p w_ip m_p EE_p,      G_i = l0 e_i / m_i       (eq. 6.10, l0 = delta)

A node is flagged (an "Eigenerosion Enhanced" corner, 6.3.1) when G_i >= G_EE; a particle of an
SPB material becomes peridynamic when a corner of its cell is flagged.

Corrections to the print: eq. 6.10's sigma+ sums every eigenpair (that is sigma itself): only
the positive principal stresses count here. In 2D (plane strain) sigma is the in-plane 2x2
stress. The 2D tensile part is closed-form (the projector (sigma - s2 I)/(s1 - s2) onto the
larger principal direction); 3D uses cyclic Jacobi rotations on scalars in registers, which
converge quadratically and stay accurate for repeated eigenvalues (uniaxial stress has two).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..kernels.deformation import volume_ratio
from ..kernels.shape import node, stencil_weights_2d, stencil_weights_3d
from ..materials.decompositions import jacobi_angle

ENERGIES = ("stress_squared", "tensile_energy")
STRESS_SQUARED, TENSILE_ENERGY = 0, 1


@njit(cache=True, inline="always")
def tensile_part_2d(s00, s01, s11):
    """sigma+ of the symmetric 2x2 (s00, s01; s01, s11) as (p00, p01, p11)."""
    m = 0.5 * (s00 + s11)
    h = 0.5 * (s00 - s11)
    r = math.sqrt(h * h + s01 * s01)
    l1 = m + r
    l2 = m - r
    if l2 >= 0.0:
        return s00, s01, s11
    if l1 <= 0.0:
        return 0.0, 0.0, 0.0
    # l1 > 0 > l2, so r > 0: sigma+ = l1 (sigma - l2 I) / (l1 - l2).
    c = l1 / (l1 - l2)
    return c * (s00 - l2), c * s01, c * (s11 - l2)


@njit(cache=True)
def symmetric_eigen_3d(a00, a01, a02, a11, a12, a22):
    """Eigenvalues (l0, l1, l2) and eigenvectors (columns of the row-major 9-tuple V) of a
    symmetric 3x3 matrix by cyclic Jacobi: sweeps over (0,1), (0,2), (1,2) until the
    off-diagonal part is below 1e-300 or 1e-17 of the diagonal scale (at most 12 sweeps;
    double precision converges in 3-5)."""
    v00, v01, v02 = 1.0, 0.0, 0.0
    v10, v11, v12 = 0.0, 1.0, 0.0
    v20, v21, v22 = 0.0, 0.0, 1.0
    for _ in range(12):
        off = a01 * a01 + a02 * a02 + a12 * a12
        scale = a00 * a00 + a11 * a11 + a22 * a22
        if off <= 1e-34 * scale or off < 1e-300:
            break
        if a01 != 0.0:                                   # pair (0, 1)
            c, s, _ = jacobi_angle(a00, a11, a01)
            n00 = c * c * a00 - 2.0 * s * c * a01 + s * s * a11
            n11 = s * s * a00 + 2.0 * s * c * a01 + c * c * a11
            n02 = c * a02 - s * a12
            n12 = s * a02 + c * a12
            a00, a11, a01, a02, a12 = n00, n11, 0.0, n02, n12
            v00, v01 = c * v00 - s * v01, s * v00 + c * v01
            v10, v11 = c * v10 - s * v11, s * v10 + c * v11
            v20, v21 = c * v20 - s * v21, s * v20 + c * v21
        if a02 != 0.0:                                   # pair (0, 2)
            c, s, _ = jacobi_angle(a00, a22, a02)
            n00 = c * c * a00 - 2.0 * s * c * a02 + s * s * a22
            n22 = s * s * a00 + 2.0 * s * c * a02 + c * c * a22
            n01 = c * a01 - s * a12
            n12 = s * a01 + c * a12
            a00, a22, a02, a01, a12 = n00, n22, 0.0, n01, n12
            v00, v02 = c * v00 - s * v02, s * v00 + c * v02
            v10, v12 = c * v10 - s * v12, s * v10 + c * v12
            v20, v22 = c * v20 - s * v22, s * v20 + c * v22
        if a12 != 0.0:                                   # pair (1, 2)
            c, s, _ = jacobi_angle(a11, a22, a12)
            n11 = c * c * a11 - 2.0 * s * c * a12 + s * s * a22
            n22 = s * s * a11 + 2.0 * s * c * a12 + c * c * a22
            n01 = c * a01 - s * a02
            n02 = s * a01 + c * a02
            a11, a22, a12, a01, a02 = n11, n22, 0.0, n01, n02
            v01, v02 = c * v01 - s * v02, s * v01 + c * v02
            v11, v12 = c * v11 - s * v12, s * v11 + c * v12
            v21, v22 = c * v21 - s * v22, s * v21 + c * v22
    return a00, a11, a22, (v00, v01, v02, v10, v11, v12, v20, v21, v22)


@njit(cache=True, inline="always")
def tensile_part_3d(s00, s01, s02, s11, s12, s22):
    """sigma+ of a symmetric 3x3 as (p00, p01, p02, p11, p12, p22)."""
    l0, l1, l2, V = symmetric_eigen_3d(s00, s01, s02, s11, s12, s22)
    if l0 >= 0.0 and l1 >= 0.0 and l2 >= 0.0:
        return s00, s01, s02, s11, s12, s22
    k0 = max(l0, 0.0)
    k1 = max(l1, 0.0)
    k2 = max(l2, 0.0)
    # sum_k k_k V[:, k] V[:, k]^T
    p00 = k0 * V[0] * V[0] + k1 * V[1] * V[1] + k2 * V[2] * V[2]
    p01 = k0 * V[0] * V[3] + k1 * V[1] * V[4] + k2 * V[2] * V[5]
    p02 = k0 * V[0] * V[6] + k1 * V[1] * V[7] + k2 * V[2] * V[8]
    p11 = k0 * V[3] * V[3] + k1 * V[4] * V[4] + k2 * V[5] * V[5]
    p12 = k0 * V[3] * V[6] + k1 * V[4] * V[7] + k2 * V[5] * V[8]
    p22 = k0 * V[6] * V[6] + k1 * V[7] * V[7] + k2 * V[8] * V[8]
    return p00, p01, p02, p11, p12, p22


@njit(cache=True, inline="always")
def _phi(pp, tr, code, E, nu):
    """Phi from sigma+:sigma+ (pp) and tr sigma+ (tr)."""
    if code == STRESS_SQUARED:
        return pp
    return ((1.0 + nu) * pp - nu * tr * tr) / (2.0 * E)


@njit(cache=True, inline="always")
def phi_2d(tau, F, p, code, E, nu):
    """Phi(sigma+) of row p, sigma = tau / det F (2D); F may be the (n,) volume ratio J of a
    material that carries no F (`kernels.deformation.volume_ratio`)."""
    inv = 1.0 / volume_ratio(F, p)
    p00, p01, p11 = tensile_part_2d(tau[p, 0, 0] * inv,
                                    0.5 * (tau[p, 0, 1] + tau[p, 1, 0]) * inv,
                                    tau[p, 1, 1] * inv)
    return _phi(p00 * p00 + 2.0 * p01 * p01 + p11 * p11, p00 + p11, code, E, nu)


@njit(cache=True, inline="always")
def _frob_sym3(a00, a01, a02, a11, a12, a22):
    return a00 * a00 + a11 * a11 + a22 * a22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)


@njit(cache=True, inline="always")
def phi_3d(tau, F, p, code, E, nu, floor):
    """max(floor, Phi(sigma+)) of row p, sigma = tau / det F (3D). The eigen-solve is skipped
    where it cannot matter: when the bound Phi <= c sigma:sigma (c = 1 for stress_squared,
    max(1 + nu, 1 - 2 nu) / (2E) for tensile_energy, since sigma+:sigma+ <= sigma:sigma and
    (tr sigma+)^2 <= 3 sigma+:sigma+) is below ``floor`` (the history EE_p), and when the
    Gershgorin discs put every eigenvalue on one side of 0 (sigma+ = sigma or 0)."""
    inv = 1.0 / volume_ratio(F, p)
    s00, s11, s22 = tau[p, 0, 0] * inv, tau[p, 1, 1] * inv, tau[p, 2, 2] * inv
    s01 = 0.5 * (tau[p, 0, 1] + tau[p, 1, 0]) * inv
    s02 = 0.5 * (tau[p, 0, 2] + tau[p, 2, 0]) * inv
    s12 = 0.5 * (tau[p, 1, 2] + tau[p, 2, 1]) * inv
    ss = _frob_sym3(s00, s01, s02, s11, s12, s22)
    c = 1.0 if code == STRESS_SQUARED else max(1.0 + nu, 1.0 - 2.0 * nu) / (2.0 * E)
    if c * ss <= floor:
        return floor
    r0 = abs(s01) + abs(s02)
    r1 = abs(s01) + abs(s12)
    r2 = abs(s02) + abs(s12)
    if s00 - r0 >= 0.0 and s11 - r1 >= 0.0 and s22 - r2 >= 0.0:
        phi = _phi(ss, s00 + s11 + s22, code, E, nu)           # sigma+ = sigma
        return max(phi, floor)
    if s00 + r0 <= 0.0 and s11 + r1 <= 0.0 and s22 + r2 <= 0.0:
        return max(0.0, floor)                                   # sigma+ = 0
    p00, p01, p02, p11, p12, p22 = tensile_part_3d(s00, s01, s02, s11, s12, s22)
    pp = _frob_sym3(p00, p01, p02, p11, p12, p22)
    return max(_phi(pp, p00 + p11 + p22, code, E, nu), floor)


@njit(cache=True)
def energy_history_2d(x, mass, tau, F, EE, code, E, nu, order, dx, domain_lo, origin,
                      grid_energy):
    """One pass over a chunk (2D): EE_p = max(EE_p, Phi(sigma+_p)) and e_i += w_ip m_p EE_p
    (the numerator of eq. 6.10). x, tau, F, mass, EE: the chunk's rows; ``order`` is
    `kernels.transfer.static` of the kernel order."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        phi = phi_2d(tau, F, p, code, E, nu)
        if phi > EE[p]:
            EE[p] = phi
        me = mass[p] * EE[p]
        if me == 0.0:
            continue
        w0, w1, l0, l1 = stencil_weights_2d(x, p, order, inv_dx, domain_lo, origin)
        for i in range(node(s)):
            for j in range(node(s)):
                grid_energy[l0 + i, l1 + j] += w0[i] * w1[j] * me


@njit(cache=True)
def energy_history_3d(x, mass, tau, F, EE, code, E, nu, order, dx, domain_lo, origin,
                      grid_energy):
    """3D `energy_history_2d`."""
    order = len(order)
    inv_dx = 1.0 / dx
    s = order + 1
    for p in range(x.shape[0]):
        EE[p] = phi_3d(tau, F, p, code, E, nu, EE[p])
        me = mass[p] * EE[p]
        if me == 0.0:
            continue
        w0, w1, w2, l0, l1, l2 = stencil_weights_3d(x, p, order, inv_dx, domain_lo, origin)
        for i in range(node(s)):
            for j in range(node(s)):
                wij = w0[i] * w1[j] * me
                for kk in range(node(s)):
                    grid_energy[l0 + i, l1 + j, l2 + kk] += wij * w2[kk]


ENERGY_HISTORY = {2: energy_history_2d, 3: energy_history_3d}


@njit(cache=True)
def grid_energy_release(grid_energy, grid_mass, l0, out):
    """G_i = l0 e_i / m_i (0 where m_i = 0), over the flattened block (``out`` may be
    ``grid_energy``); returns max_i G_i. Right on owned nodes only, where e and m are complete
    after the ghost sum: fill the ghosts from the owners afterwards. (A ghost's partial sums
    may give a larger G, never a missed one: the maximum over all ranks bounds every G_i.)"""
    e = grid_energy.reshape(-1)
    m = grid_mass.reshape(-1)
    o = out.reshape(-1)
    top = 0.0
    for i in range(e.shape[0]):
        o[i] = l0 * e[i] / m[i] if m[i] > 0.0 else 0.0
        if o[i] > top:
            top = o[i]
    return top


@njit(cache=True)
def flagged_particles_2d(x, v, dt, rows, model, grid_G, threshold, domain_lo, dx, origin, out):
    """Rows p in ``rows`` still MPM (model 0) whose cell at x^n = x - dt v has a corner node
    with G_i >= threshold (003 §6.3.1; ``grid_G`` from `grid_energy_release`, complete on
    ghost nodes too). Writes them into ``out``; returns how many, and the smallest
    |G_i - threshold| / threshold over the corners looked at (the margin that rank-count
    round-off must not cross)."""
    count = 0
    margin = np.inf
    inv_dx = 1.0 / dx
    for k in range(rows.shape[0]):
        p = rows[k]
        if model[p] != 0:
            continue
        c0 = int(math.floor((x[p, 0] - dt * v[p, 0] - domain_lo[0]) * inv_dx)) - origin[0]
        c1 = int(math.floor((x[p, 1] - dt * v[p, 1] - domain_lo[1]) * inv_dx)) - origin[1]
        hit = False
        for i in range(2):
            for j in range(2):
                G = grid_G[c0 + i, c1 + j]
                margin = min(margin, abs(G - threshold) / threshold)
                if G >= threshold:
                    hit = True
        if hit:
            out[count] = p
            count += 1
    return count, margin


@njit(cache=True)
def flagged_particles_3d(x, v, dt, rows, model, grid_G, threshold, domain_lo, dx, origin, out):
    """3D `flagged_particles_2d`."""
    count = 0
    margin = np.inf
    inv_dx = 1.0 / dx
    for k in range(rows.shape[0]):
        p = rows[k]
        if model[p] != 0:
            continue
        c0 = int(math.floor((x[p, 0] - dt * v[p, 0] - domain_lo[0]) * inv_dx)) - origin[0]
        c1 = int(math.floor((x[p, 1] - dt * v[p, 1] - domain_lo[1]) * inv_dx)) - origin[1]
        c2 = int(math.floor((x[p, 2] - dt * v[p, 2] - domain_lo[2]) * inv_dx)) - origin[2]
        hit = False
        for i in range(2):
            for j in range(2):
                for kk in range(2):
                    G = grid_G[c0 + i, c1 + j, c2 + kk]
                    margin = min(margin, abs(G - threshold) / threshold)
                    if G >= threshold:
                        hit = True
        if hit:
            out[count] = p
            count += 1
    return count, margin


FLAGGED_PARTICLES = {2: flagged_particles_2d, 3: flagged_particles_3d}

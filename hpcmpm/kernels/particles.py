"""Per-particle scans: the health check and speed for the time step, sort keys, and the
kinetic/momentum diagnostics."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .deformation import volume_ratio


@njit(cache=True)
def scan_health(x, v, F, bad, max_report, lo, hi):
    """Largest particle speed and the indices of broken particles.

    A particle is broken when x, v or F holds a non-finite value, |v|^2 overflows, det F <= 0
    (an inverted or collapsed element: the stress models are undefined there) or x lies outside
    [lo, hi] (far beyond the domain: a blown-up state, which would next ask for a grid block
    reaching it). F may be the (n,) volume ratio J of a scene of volumetric materials
    (`hpcmpm.kernels.deformation`). Writes up to ``max_report`` indices into ``bad``;
    returns (max speed, number of broken particles)."""
    n, dim = x.shape
    vmax2 = 0.0
    nbad = 0
    for p in range(n):
        s = 0.0
        ok = True
        for a in range(dim):
            s += v[p, a] * v[p, a]
            if not (lo[a] <= x[p, a] <= hi[a] and math.isfinite(v[p, a])):
                ok = False
        J = volume_ratio(F, p)
        if not (math.isfinite(J) and J > 0.0):
            ok = False
        if not math.isfinite(s):
            # |v|^2 overflows (|v| > 1.3e154): the speed would be inf and the time step 0,
            # a run that loops without advancing (a fuzzed velocity of 1e299 did).
            ok = False
        if ok:
            if s > vmax2:
                vmax2 = s
        else:
            if nbad < max_report:
                bad[nbad] = p
            nbad += 1
    return math.sqrt(vmax2), nbad


# Sort-key cells are clamped to [-SORT_CELL_LIMIT, SORT_CELL_LIMIT) per axis (2**17 in 3D,
# 2**26 in 2D): then (cells per axis)^dim * groups stays below 2**62 for up to 256 groups, so
# a particle flung far outside the domain cannot overflow the key and break the group
# order. Clamping merges far cells into one key, which only coarsens the cell order there.
SORT_CELL_LIMIT_2D, SORT_CELL_LIMIT_3D = 1 << 26, 1 << 17


@njit(cache=True)
def _sort_cell(x, lo, inv_dx, limit):
    c = (x - lo) * inv_dx
    if not (c > -limit):  # NaN too: a broken particle, reported by the health check
        return -limit
    if c >= limit:
        return limit - 1
    return int(math.floor(c))


@njit(cache=True)
def cell_sort_keys(x, group, domain_lo, inv_dx, keys):
    """Sort key ``(group, cell)`` packed in an int64: cells in row-major order over the
    particles' bounding box of cells, groups outermost so each material's particles are one
    contiguous slice. Cells are clamped to +-SORT_CELL_LIMIT so the key cannot overflow.
    Writes ``keys`` (n,); returns the number of distinct key values (1 + the largest
    possible key), for a counting sort."""
    n, dim = x.shape
    if n == 0:
        return 0
    limit = SORT_CELL_LIMIT_3D if dim == 3 else SORT_CELL_LIMIT_2D
    lo = np.empty(dim, dtype=np.int64)
    hi = np.empty(dim, dtype=np.int64)
    for a in range(dim):
        lo[a] = 1 << 62
        hi[a] = -(1 << 62)
    for p in range(n):
        for a in range(dim):
            c = _sort_cell(x[p, a], domain_lo[a], inv_dx, limit)
            lo[a] = min(lo[a], c)
            hi[a] = max(hi[a], c)
    ncell = 1
    for a in range(dim):
        ncell *= hi[a] - lo[a] + 1
    for p in range(n):
        lin = 0
        for a in range(dim):
            c = _sort_cell(x[p, a], domain_lo[a], inv_dx, limit)
            lin = lin * (hi[a] - lo[a] + 1) + (c - lo[a])
        keys[p] = group[p] * ncell + lin
    n_groups = 0
    for p in range(n):
        n_groups = max(n_groups, group[p] + 1)
    return n_groups * ncell


@njit(cache=True)
def counting_sort_order(keys, n_keys, order, counts):
    """Stable permutation sorting ``keys`` (values in [0, n_keys)) in O(n + n_keys).

    ``counts`` is caller-owned scratch of length >= n_keys + 1; writes ``order`` (n,)."""
    for k in range(n_keys + 1):
        counts[k] = 0
    for p in range(keys.shape[0]):
        counts[keys[p] + 1] += 1
    for k in range(n_keys):
        counts[k + 1] += counts[k]
    for p in range(keys.shape[0]):
        k = keys[p]
        order[counts[k]] = p
        counts[k] += 1


@njit(cache=True)
def momentum_and_kinetic_energy(x, v, mass, C, with_affine, inertia):
    """Linear momentum (3,), angular momentum about the origin (3,), kinetic energy.

    With APIC/MLS the affine velocity field carries angular momentum too (Jiang 2015 §5.3):
    ``L_p = x_p x m_p v_p + m_p D eps : C_p`` with ``D = inertia I``."""
    n, dim = x.shape
    out = np.zeros(7)
    for p in range(n):
        m = mass[p]
        x0, x1 = x[p, 0], x[p, 1]
        v0, v1 = v[p, 0], v[p, 1]
        x2 = x[p, 2] if dim == 3 else 0.0
        v2 = v[p, 2] if dim == 3 else 0.0
        out[0] += m * v0
        out[1] += m * v1
        out[2] += m * v2
        out[3] += m * (x1 * v2 - x2 * v1)
        out[4] += m * (x2 * v0 - x0 * v2)
        out[5] += m * (x0 * v1 - x1 * v0)
        if with_affine:
            # eps_abc C_bc: the antisymmetric part of C is the spin of the affine field.
            if dim == 3:
                out[3] += m * inertia * (C[p, 2, 1] - C[p, 1, 2])
                out[4] += m * inertia * (C[p, 0, 2] - C[p, 2, 0])
            out[5] += m * inertia * (C[p, 1, 0] - C[p, 0, 1])
        out[6] += 0.5 * m * (v0 * v0 + v1 * v1 + v2 * v2)
    return out


@njit(cache=True)
def complete_permutation(order, n, perm, chosen):
    """``perm`` (n,) = ``order`` (m distinct indices into 0..n-1) followed by the indices it
    leaves out, in increasing order, so a subset selection becomes a permutation that
    `permute_rows` can apply in place. ``chosen`` is (n,) bool scratch."""
    m = order.shape[0]
    for i in range(n):
        chosen[i] = False
    for j in range(m):
        perm[j] = order[j]
        chosen[order[j]] = True
    k = m
    for i in range(n):
        if not chosen[i]:
            perm[k] = i
            k += 1


@njit(cache=True)
def permute_rows(data, perm, done, row):
    """``data[j] <- data[perm[j]]`` for every row j, in place, following the permutation's
    cycles: one row of scratch (``row``, (w,)) instead of a second copy of the array.

    data (n, w); perm (n,) a permutation of 0..n-1; done (n,) bool scratch."""
    n, w = data.shape
    for i in range(n):
        done[i] = False
    for i in range(n):
        if done[i]:
            continue
        done[i] = True
        if perm[i] == i:
            continue
        for c in range(w):
            row[c] = data[i, c]
        j = i
        while True:
            k = perm[j]
            done[j] = True
            if k == i:
                for c in range(w):
                    data[j, c] = row[c]
                break
            for c in range(w):
                data[j, c] = data[k, c]
            j = k

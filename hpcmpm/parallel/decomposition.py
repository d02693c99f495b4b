"""Recursive coordinate bisection (RCB) of the cell index space, and the owner lookup.

A rank owns a box of cells ``[lo, hi)`` (global indices, ARCHITECTURE.md); the boxes tile the
whole index space, the outermost faces sitting at ``+-BIG`` (at ``0`` and ``n_cells`` on a
periodic axis, whose positions are wrapped into the domain). The bisection is computed from
global histograms only, so every rank derives the same boxes from the same reductions.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from numba import njit

# Outer faces of the outermost boxes: "infinity" that still fits int64 arithmetic.
BIG = 2**40

# Neutral element for the max-reduction of particle extents of a node with no particles.
_EMPTY = -(2**62)


def particle_cells(x: np.ndarray, domain_lo: np.ndarray, inv_dx: float) -> np.ndarray:
    """Cell index of each particle, ``floor((x - domain_lo) * inv_dx)``, shape (n, dim) int64.

    The same expression (multiply by ``1/dx``) as the transfer kernels, so a particle on a cell
    face lands in the same cell here and in P2G. Non-finite positions map to cell 0 so that a
    blown-up particle cannot make an astronomically large box (the instability guard reports it).
    One pass with no temporaries: the NumPy version held five (n, dim) copies at once, which
    set the peak memory of a run's start-up.
    """
    out = np.empty(x.shape, dtype=np.int64)
    _particle_cells(np.ascontiguousarray(x, dtype=np.float64),
                    np.asarray(domain_lo, dtype=np.float64), float(inv_dx), out)
    return out


@njit(cache=True)
def _particle_cells(x, domain_lo, inv_dx, out):
    n, dim = x.shape
    for p in range(n):
        for a in range(dim):
            xi = (x[p, a] - domain_lo[a]) * inv_dx
            if not math.isfinite(xi):
                xi = 0.0
            out[p, a] = int(math.floor(min(max(xi, -BIG), BIG - 1)))


@njit(cache=True)
def owner_ranks(x, domain_lo, inv_dx, boxes, me, out):
    """Rank whose cell box holds each particle; out (n,) int64. Non-finite positions keep
    ``me``. (Migration asks `leavers` for the few particles that move instead.)"""
    n = x.shape[0]
    index = np.empty(n, dtype=np.int64)
    owner = np.empty(n, dtype=np.int64)
    search = np.empty(boxes.shape[0], dtype=np.int64)
    search[0] = me
    k = 1
    for b in range(boxes.shape[0]):
        if b != me:
            search[k] = b
            k += 1
    k = leavers(x, domain_lo, inv_dx, boxes, search, index, owner)
    for p in range(n):
        out[p] = me
    for j in range(k):
        out[index[j]] = owner[j]
    return out


@njit(cache=True)
def leavers(x, domain_lo, inv_dx, boxes, search, index, owner):
    """Particles whose cell is outside this rank's box (``boxes[search[0]]``): writes their
    indices (increasing) to ``index`` and their owners to ``owner`` (both at least as long as
    x) and returns how many. The other boxes are tried in the order of ``search`` (the
    neighbours first: a step's leavers stop there). Non-finite positions stay (the
    instability guard reports them), as do positions in no box (beyond +-BIG cells).

    floor(xi) >= lo <=> xi >= lo and floor(xi) < hi <=> xi < hi for integers lo, hi, so the
    cell test compares the grid coordinate with the box as floats, without a floor; the
    own box is held in scalars, the test most particles end with."""
    n, dim = x.shape
    three = dim == 3
    me = search[0]
    flo = boxes[:, 0, :].astype(np.float64)
    fhi = boxes[:, 1, :].astype(np.float64)
    d0, d1 = domain_lo[0], domain_lo[1]
    d2 = domain_lo[2] if three else 0.0
    l0, l1, h0, h1 = flo[me, 0], flo[me, 1], fhi[me, 0], fhi[me, 1]
    l2 = flo[me, 2] if three else -1.0
    h2 = fhi[me, 2] if three else 1.0
    count = 0
    for p in range(n):
        c0 = (x[p, 0] - d0) * inv_dx
        c1 = (x[p, 1] - d1) * inv_dx
        c2 = (x[p, 2] - d2) * inv_dx if three else 0.0
        if c0 >= l0 and c0 < h0 and c1 >= l1 and c1 < h1 and c2 >= l2 and c2 < h2:
            continue
        if not (abs(c0) < BIG and abs(c1) < BIG and abs(c2) < BIG):  # false for NaN too
            continue
        for j in range(1, search.shape[0]):
            b = search[j]
            if (c0 >= flo[b, 0] and c0 < fhi[b, 0] and c1 >= flo[b, 1] and c1 < fhi[b, 1]
                    and (not three or (c2 >= flo[b, 2] and c2 < fhi[b, 2]))):
                index[count] = p
                owner[count] = b
                count += 1
                break
    return count


@njit(cache=True)
def cell_bounds(x, domain_lo, inv_dx, lo, hi):
    """Smallest and largest particle cell per axis in one pass, written to lo, hi (d,) int64.
    Non-finite positions are skipped (the instability guard reports them). Returns the number
    of particles counted.

    Tracks the extreme coordinates and floors only those (floor is monotonic, so the result
    is the same as flooring every particle, at a quarter of the cost)."""
    n, dim = x.shape
    # Scalars, not small arrays: they stay in registers through the loop.
    mn0 = mn1 = mn2 = np.inf
    mx0 = mx1 = mx2 = -np.inf
    count = 0
    for p in range(n):
        x0 = x[p, 0]
        x1 = x[p, 1]
        x2 = x[p, 2] if dim == 3 else 0.0
        if not math.isfinite(x0 + x1 + x2):  # inf or nan in some coordinate
            continue
        count += 1
        mn0, mx0 = min(mn0, x0), max(mx0, x0)
        mn1, mx1 = min(mn1, x1), max(mx1, x1)
        mn2, mx2 = min(mn2, x2), max(mx2, x2)
    xmin = (mn0, mn1, mn2)
    xmax = (mx0, mx1, mx2)
    for a in range(dim):
        if count:
            lo[a] = int(math.floor(min(max((xmin[a] - domain_lo[a]) * inv_dx, -BIG), BIG)))
            hi[a] = int(math.floor(min(max((xmax[a] - domain_lo[a]) * inv_dx, -BIG), BIG)))
        else:
            lo[a] = BIG
            hi[a] = -BIG
    return count


@njit(cache=True)
def _inside(x, p, lo, hi, k):
    for a in range(x.shape[1]):
        if not (x[p, a] >= lo[k, a] and x[p, a] <= hi[k, a]):
            return False
    return True


@njit(cache=True)
def points_in_boxes(x, lo, hi):
    """Indices of the points inside each closed box ``[lo[k], hi[k]]`` (k, d) float64, grouped
    by box (a point may be in several). Returns (counts (k,), index (counts.sum(),))."""
    n_boxes = lo.shape[0]
    counts = np.zeros(n_boxes, np.int64)
    for p in range(x.shape[0]):
        for k in range(n_boxes):
            if _inside(x, p, lo, hi, k):
                counts[k] += 1
    fill = np.zeros(n_boxes, np.int64)
    for k in range(1, n_boxes):
        fill[k] = fill[k - 1] + counts[k - 1]
    index = np.empty(counts.sum(), np.int64)
    for p in range(x.shape[0]):
        for k in range(n_boxes):
            if _inside(x, p, lo, hi, k):
                index[fill[k]] = p
                fill[k] += 1
    return counts, index


@njit(cache=True)
def wrap_periodic(x, domain_lo, inv_dx, dx, period, follow):
    """Wrap positions into the domain along the periodic axes, in place:
    ``x <- lo + (x - lo) mod L`` with ``L = period * dx`` (``period[a] = 0``: axis a is not
    periodic). Positions already inside (most of them) are only compared; non-finite ones are
    left for the instability guard. Returns the number of coordinates wrapped.

    ``follow`` (n, dim), or no rows: positions that move with x by the same whole periods,
    ``k L`` exactly (the reference positions of peridynamic particles: x - x0 stays the
    displacement, however far a body travels).

    ``(x - lo) mod L`` can round up to ``L`` (a coordinate a hair below ``lo``); the image of
    the upper face is the lower one, so such a coordinate becomes ``lo``. The test uses the
    cell expression of the transfer kernels, so a wrapped particle's cell is in [0, period)."""
    n, dim = x.shape
    wrapped = 0
    for p in range(n):
        for a in range(dim):
            m = period[a]
            if m == 0:
                continue
            xi = (x[p, a] - domain_lo[a]) * inv_dx
            if (xi >= 0.0 and xi < m) or not math.isfinite(xi):
                continue
            y = domain_lo[a] + (x[p, a] - domain_lo[a]) % (m * dx)
            xi = (y - domain_lo[a]) * inv_dx
            if not (xi >= 0.0 and xi < m):
                y = domain_lo[a]
            if follow.shape[0]:
                follow[p, a] += round((y - x[p, a]) / (m * dx)) * (m * dx)
            x[p, a] = y
            wrapped += 1
    return wrapped


def _choose_cut(hist: np.ndarray, first: int, n_left: int, n_ranks: int) -> int:
    """Cell index ``c`` that puts the weighted ``n_left/n_ranks`` quantile of ``hist`` (counts
    of cells ``first, first+1, ...``) below it; both sides keep at least one cell column."""
    length = len(hist)
    if length < 2:
        return first + 1
    target = hist.sum() * n_left / n_ranks
    below = np.cumsum(hist)[:-1]  # particles left of the cut first + k, k = 1..length-1
    k = int(np.argmin(np.abs(below - target))) + 1  # ties -> smallest k: deterministic
    return first + k


def _empty_cut(lo: np.ndarray, hi: np.ndarray, n_cells: np.ndarray, n_left: int, n_ranks: int):
    """Split a box that holds no particle: the longest axis of its part of the domain,
    proportionally to the rank counts (so a later particle still finds a sensible owner)."""
    e_lo = np.maximum(lo, -1)
    e_hi = np.minimum(hi, n_cells + 1)
    length = e_hi - e_lo
    axis = int(np.argmax(length))
    if length[axis] >= 2:
        k = int(np.clip(round(length[axis] * n_left / n_ranks), 1, length[axis] - 1))
        return axis, int(e_lo[axis] + k)
    return axis, int(np.clip(e_lo[axis] + 1, lo[axis], hi[axis]))


def recursive_bisection(cells: np.ndarray, size: int, n_cells: np.ndarray,
                        reduce_max: Callable[[np.ndarray], np.ndarray],
                        reduce_sum: Callable[[np.ndarray], np.ndarray],
                        periodic=None, weights: np.ndarray | None = None) -> np.ndarray:
    """Boxes of cells, one per rank, by recursive coordinate bisection weighted by particles
    (by their ``weights`` when given: integer costs, e.g. a peridynamic particle's bonds,
    `Simulation.load_weights`; integers keep the global histograms exact, so every rank
    derives the same cuts on any rank count).

    The rank range of a box is split in two (``floor``/``ceil`` halves); the box is cut along
    the longest axis of its particles' global extent, at the weighted quantile given by the
    global histogram of particle cells along that axis. All boxes of one tree level share one
    max-reduction (extents) and one sum-reduction (histograms), so the whole decomposition costs
    ``2 ceil(log2 size)`` small collectives.

    cells : (n, dim) int64 cells of this rank's particles.
    reduce_max, reduce_sum : elementwise reductions of int64 arrays over all ranks.
    weights : (n,) int64 cost of each particle (None: 1 each).
    periodic : (dim,) bool, axes whose cells wrap: there the boxes tile ``[0, n_cells)``
        exactly (no particle lies outside once positions are wrapped), elsewhere the outermost
        faces sit at ``+-BIG``.
    Returns boxes (size, 2, dim) int64, ``boxes[r] = [lo, hi)``.
    """
    dim = cells.shape[1]
    n_cells = np.asarray(n_cells, dtype=np.int64)
    periodic = np.zeros(dim, bool) if periodic is None else np.asarray(periodic, bool)
    # Cells beyond the domain are clamped for the histograms only: every cut lies inside
    # [0, n_cells], so a clamped cell falls on the same side of it as the true one.
    if len(cells) and (cells.min() < -1 or np.any(cells.max(axis=0) > n_cells)):
        cells = np.clip(cells, -1, n_cells)  # a copy only when some particle is outside
    boxes = np.empty((size, 2, dim), dtype=np.int64)
    # Tree nodes of the current level: (first rank, end rank, lo, hi, particle index).
    level = [(0, size, np.where(periodic, 0, -BIG).astype(np.int64),
              np.where(periodic, n_cells, BIG).astype(np.int64),
              np.arange(len(cells)))]
    while level:
        for r0, r1, lo, hi, _ in level:
            if r1 - r0 == 1:
                boxes[r0, 0], boxes[r0, 1] = lo, hi
        level = [node for node in level if node[1] - node[0] > 1]
        if not level:
            break
        extents = np.full((len(level), 2, dim), _EMPTY, dtype=np.int64)
        for i, (*_, index) in enumerate(level):
            if len(index):
                extents[i, 0] = -cells[index].min(axis=0)
                extents[i, 1] = cells[index].max(axis=0)
        extents = reduce_max(extents)
        first, last = -extents[:, 0], extents[:, 1]
        axes = np.argmax(last - first, axis=1)
        lengths = np.where(last[:, 0] >= first[:, 0],
                           last[np.arange(len(level)), axes] - first[np.arange(len(level)), axes]
                           + 1, 0)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        hist = np.zeros(offsets[-1], dtype=np.int64)
        for i, (*_, index) in enumerate(level):
            if lengths[i] and len(index):
                a = axes[i]
                hist[offsets[i]:offsets[i + 1]] = np.bincount(
                    cells[index, a] - first[i, a], minlength=lengths[i]) if weights is None \
                    else _weighted_bincount(cells[index, a] - first[i, a], weights[index],
                                            lengths[i])
        hist = reduce_sum(hist)
        children = []
        for i, (r0, r1, lo, hi, index) in enumerate(level):
            n_left = (r1 - r0) // 2
            if lengths[i]:
                axis = int(axes[i])
                cut = _choose_cut(hist[offsets[i]:offsets[i + 1]], int(first[i, axis]),
                                  n_left, r1 - r0)
            else:
                axis, cut = _empty_cut(lo, hi, n_cells, n_left, r1 - r0)
            left = cells[index, axis] < cut
            lo_right, hi_left = lo.copy(), hi.copy()
            hi_left[axis] = lo_right[axis] = cut
            children.append((r0, r0 + n_left, lo, hi_left, index[left]))
            children.append((r0 + n_left, r1, lo_right, hi, index[~left]))
        level = children
    return boxes


@njit(cache=True)
def _weighted_bincount(bins, weights, length):
    """np.bincount with integer weights, summed as int64 (np.bincount sums floats)."""
    out = np.zeros(length, dtype=np.int64)
    for k in range(len(bins)):
        out[bins[k]] += weights[k]
    return out


def neighbour_ranks(boxes: np.ndarray, me: int, shifts: np.ndarray, reach: int) -> np.ndarray:
    """Ranks whose box, or one of its images ``box + shift``, lies within ``reach`` cells of
    box ``me``: on every axis each box's upper face plus ``reach`` passes the other's lower
    face. Symmetric, also for an empty box (``lo == hi``: a rank without cells, as when a
    domain has fewer cells than ranks); the test "the other box meets mine expanded" is not,
    since an empty box meets nothing, and a rank that listed an empty neighbour which did
    not list it back waited for it forever in the neighbour collectives. Sorted, without
    me."""
    lo, hi = boxes[:, 0], boxes[:, 1]
    mine_lo, mine_hi = boxes[me, 0], boxes[me, 1]
    found = np.zeros(len(boxes), dtype=bool)
    for s in shifts:
        found |= np.all((mine_hi + reach > lo + s) & (hi + s + reach > mine_lo), axis=1)
    found[me] = False
    return np.flatnonzero(found).astype(np.int64)


def intersect(lo_a, hi_a, lo_b, hi_b):
    """Intersection of boxes ``[lo, hi)`` (arrays broadcast); empty when any ``hi <= lo``."""
    return np.maximum(lo_a, lo_b), np.minimum(hi_a, hi_b)


def is_empty(lo, hi) -> bool:
    return bool(np.any(np.asarray(hi) <= np.asarray(lo)))

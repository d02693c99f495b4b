"""Peridynamic families: the bonds of each particle, found once in the reference configuration.

`find_families` searches owned + halo points with an exact cell list (cells of the search
radius, points sorted by cell, rows of cells found by binary search), so the cost is that of a
sort plus a constant number of candidates per point. A bond p-q exists when

    |X| = |x0_q - x0_p| < delta + dx/2      (partial volumes on, the default)
    |X| <= delta                             (partial volumes off)

its reference segment crosses no pre-crack, and its weight omega(|X|) * beta(|X|) > 0.

Partial volumes (PA-HHB: Hu, Ha & Bobaru 2012, CMAME 217; compared in Seleson 2014, CMAME
278, eq. 14): the fraction of a cubic cell of side dx centred on the partner that lies inside
the horizon, estimated linearly along the bond,

    beta = 1                                 |X| <= delta - dx/2
    beta = (delta + dx/2 - |X|) / dx         delta - dx/2 < |X| < delta + dx/2.

The issue's family rule (|X| <= delta) would drop the partners with delta < |X| < delta + dx/2
that this rule weights: with them the PMB lattice factors at delta = 3.015 dx are the
issue's 1.059 (3D) and 1.018 (2D); truncated at delta (LAMMPS PERI's rule, which only scales
partners inside the cutoff) they are 0.890 and 0.862 (the same lattice sums as
tests/verification/test_pd_uniform.py, with beta = 0 beyond delta).

Influence functions omega(|X|): constant 1, inverse delta/|X|, conical max(1 - |X|/delta, 0),
gaussian exp(-(|X|/delta)^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .bonds import Bonds, image_label

INFLUENCES = ("constant", "inverse", "conical", "gaussian")
DEFAULT_HORIZON = 3.015  # in particle spacings (Silling & Askari 2005 use 3.015 dx)
# The largest horizon a scene may ask, in particle spacings. Horizons are a few spacings
# (3.015 above; m-convergence studies go to tens). At 256 a complete family holds about
# 2.1e5 half-bonds in 2D and 7.1e7 in 3D (1.7 GB for one particle), and only a particle
# 256 spacings from every face has one. Above it the lattice sums and the memory estimate
# alone take minutes (a typo such as horizon = 3e3 ran `hpcmpm validate` out of memory).
MAX_HORIZON_SPACINGS = 256.0


def horizon_problem(dim: int, spacings: float) -> str | None:
    """Why a horizon of ``spacings`` particle spacings is refused, or None."""
    if spacings <= MAX_HORIZON_SPACINGS:
        return None
    r = spacings + 0.5
    bonds = math.pi * r * r if dim == 2 else 4.0 / 3.0 * math.pi * r ** 3
    return (f"{spacings:.6g} particle spacings is more than {MAX_HORIZON_SPACINGS:g}: a "
            f"complete family would hold about {bonds:.2g} half-bonds per particle")


def influence_code(name: str) -> int:
    if name not in INFLUENCES:
        raise ValueError(f"influence must be one of {', '.join(INFLUENCES)}, got {name!r}")
    return INFLUENCES.index(name)


@njit(cache=True, error_model="numpy")
def influence(code, r, delta):
    """omega(|X|) for the influence function ``code`` (index into INFLUENCES)."""
    if code == 0:
        return 1.0
    if code == 1:
        return delta / r
    if code == 2:
        return max(1.0 - r / delta, 0.0)
    return math.exp(-(r / delta) * (r / delta))


@njit(cache=True, error_model="numpy")
def family_radius(delta, spacing, partial_volumes):
    """The largest bond length of a family: delta, or delta + spacing/2 with partial volumes
    (PA-HHB: a neighbour whose cell the horizon cuts is in, with a fraction of its volume)."""
    return delta + 0.5 * spacing if partial_volumes else delta


@njit(cache=True, error_model="numpy")
def partial_volume(r, delta, dx, on):
    """beta(|X|): PA-HHB partial-volume fraction (module docstring); 1 inside when ``on`` is
    False (the caller then only passes |X| <= delta)."""
    if not on:
        return 1.0
    if r <= delta - 0.5 * dx:
        return 1.0
    return (delta + 0.5 * dx - r) / dx


def full_family_sum(dim: int, spacing: float, delta: float, influence: str = "constant",
                    partial_volumes: bool = True, power: int = 0) -> float:
    """sum_q w |X|^power V_q over the family of a lattice point with a complete neighbourhood
    (cubic lattice of ``spacing``, V_q = spacing^d, the bond rule of `find_families`): the
    lattice sums of the bond-energy scale beta and of the Silling-Askari time step."""
    return _lattice_sum(dim, float(spacing), float(delta), influence_code(influence),
                        bool(partial_volumes), int(power))


@njit(cache=True, error_model="numpy")
def _lattice_sum(dim, h, delta, code, partial_volumes, power):
    """`full_family_sum` point by point: no array of the (2k + 1)^d lattice points (at the
    largest horizon a scene accepts, 256 spacings in 3D, each of numpy's grids and
    temporaries held 1.35e8 doubles, 1.1 GB; at 200 spacings validate took 3.6 minutes,
    most of it paging)."""
    r = family_radius(delta, h, partial_volumes)
    k = int(math.ceil(r / h))
    kz = k if dim == 3 else 0
    total = 0.0
    for i in range(-k, k + 1):
        xi = i * h
        for j in range(-k, k + 1):
            yj = j * h
            for m in range(-kz, kz + 1):
                zm = m * h
                dist = math.sqrt(xi * xi + yj * yj + zm * zm)
                if dist == 0.0:
                    continue
                if partial_volumes:
                    if not dist < r:
                        continue
                    frac = min(1.0, (delta + 0.5 * h - dist) / h)
                elif dist <= r:
                    frac = 1.0
                else:
                    continue
                total += influence(code, dist, delta) * frac * dist ** power
    return total * h ** dim


def influence_moment(name: str, power: int, delta: float) -> float:
    """I_k = int_0^delta omega(r) r^k dr in closed form (calibrates the PMB micromodulus and
    the fracture-energy stretch for any influence function)."""
    k = power
    if name == "constant":
        return delta ** (k + 1) / (k + 1)
    if name == "inverse":
        return delta ** (k + 1) / k
    if name == "conical":
        return delta ** (k + 1) * (1.0 / (k + 1) - 1.0 / (k + 2))
    if name == "gaussian":
        # int_0^1 t^k exp(-t^2) dt = gamma_lower((k+1)/2, 1) / 2
        return delta ** (k + 1) * 0.5 * _lower_gamma((k + 1) / 2.0, 1.0)
    raise ValueError(f"influence must be one of {', '.join(INFLUENCES)}, got {name!r}")


def _lower_gamma(s: float, x: float) -> float:
    # Series gamma(s, x) = x^s e^-x sum x^n / (s (s+1) ... (s+n)), converges fast for x = 1.
    term = 1.0 / s
    total = term
    n = 1
    while term > 1e-17 * total:
        term *= x / (s + n)
        total += term
        n += 1
    return x ** s * math.exp(-x) * total


@dataclass
class Family:
    """Result of `find_families`: the bonds of the owned points and the search parameters.

    ``image_source``/``image_shift`` are set when images were made for a periodic box: rows
    ``n_points..`` of the extended point arrays are copies of rows ``image_source`` shifted by
    ``image_shift`` (refresh them as ``x[src] + shift`` in the current configuration when the
    box does not deform, or with the deformed period)."""

    bonds: Bonds
    delta: float
    spacing: float
    radius: float
    partial_volumes: bool
    influence: str
    image_source: np.ndarray | None = None
    image_shift: np.ndarray | None = None


def horizon_length(spacing: float, horizon: float | None = DEFAULT_HORIZON,
                   horizon_length: float | None = None) -> float:
    """delta from ``horizon`` (in spacings) or an absolute ``horizon_length`` (which wins)."""
    return float(horizon_length) if horizon_length is not None else float(horizon) * spacing


def find_families(x0, ids, n_owned: int, spacing: float, delta: float, *,
                  influence: str = "constant", partial_volumes: bool = True,
                  precracks=None, period=None, period_lo=None,
                  image_period=None, homes=None) -> Family:
    """Bonds of points ``0..n_owned-1`` to every point of ``x0`` (owned then halo).

    Parameters
    ----------
    x0 : (n, d) reference positions of owned + halo points.
    ids : (n,) int64 permanent global ids.
    spacing : particle spacing dx (partial volumes).
    delta : horizon length.
    influence : one of INFLUENCES.
    precracks : 2D (k, 2, 2) segments; 3D a list of planar polygons, each (m >= 3, 3).
    period : (d,) period per axis (0 or inf: not periodic) for a periodic box starting at
        ``period_lo``; images of the points within the search radius are appended and bonds
        reach them (every image nearer than the radius, which must be below the period).
    image_period : (d,) periods of a box whose images the caller already put among the
        points (a rank's periodic halo): to label the half-bonds' images, and to stand each
        pre-crack one period either way.
    homes : (n, d) each point's own reference position (its particle's x0; the x0 of an
        image differs from it by whole periods), for the pre-crack test to write
        a bond alike at both ends (`_bond_segment`). Default ``x0``: right wherever the
        caller put no images among the points (with ``period`` the images made here are
        known).
    Returns a `Family`; its bonds' slots index the (extended) point arrays, each segment
    ordered by (partner id, image label: bonds.image_label).
    """
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    dim = x0.shape[1]
    if delta < spacing:
        raise ValueError(f"horizon {delta:g} is below one particle spacing {spacing:g}")
    radius = family_radius(delta, spacing, partial_volumes)
    homes = x0 if homes is None else np.ascontiguousarray(homes, dtype=np.float64)
    image_source = image_shift = None
    if period is not None:
        period = np.asarray(period, dtype=np.float64)
        periodic = np.isfinite(period) & (period > 0)
        if np.any(period[periodic] <= radius):
            raise ValueError(f"period {period.tolist()} must exceed the bond search radius "
                             f"{radius:g} (a particle would bond to its own image)")
        lo = np.asarray(period_lo if period_lo is not None else np.zeros(dim), np.float64)
        image_source, image_shift = periodic_images(x0, lo, np.where(periodic, period, 0.0),
                                                    radius)
        x0 = np.concatenate([x0, x0[image_source] + image_shift])
        ids = np.concatenate([ids, ids[image_source]])
        homes = np.concatenate([homes, homes[image_source]])
    labels = period if period is not None else image_period
    if labels is not None:
        labels = np.where(np.isfinite(labels) & (np.asarray(labels) > 0), labels, 0.0)
    periods = np.zeros(dim) if labels is None else np.ascontiguousarray(labels, np.float64)
    seg, poly_v, poly_off = _pack_precracks(precracks, dim, labels)
    keys, order, cell_lo, ncell = _cell_sort(x0, radius)
    code = influence_code(influence)
    counts = np.zeros(n_owned, dtype=np.int64)
    _search(x0, n_owned, keys[order], order, cell_lo, ncell, radius, delta, spacing,
            partial_volumes, code, seg, poly_v, poly_off, homes, ids, periods, counts,
            np.empty(0, np.int64), np.empty(0, np.int32), np.empty(0), True)
    offsets = np.zeros(n_owned + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    nb = int(offsets[-1])
    slot = np.empty(nb, dtype=np.int32)
    weight = np.empty(nb, dtype=np.float64)
    _search(x0, n_owned, keys[order], order, cell_lo, ncell, radius, delta, spacing,
            partial_volumes, code, seg, poly_v, poly_off, homes, ids, periods, counts, offsets,
            slot, weight, False)
    partner = ids[slot]
    image = np.zeros(nb, dtype=np.int8)
    if labels is not None:
        _label_images(offsets, slot, x0, periods, image)
    _sort_segments_by_id(offsets, partner, slot, weight, image)
    bonds = Bonds(offsets, partner, weight, slot=slot, image=image)
    return Family(bonds, float(delta), float(spacing), float(radius), bool(partial_volumes),
                  influence, image_source, image_shift)


def half_bonds_per_particle(dim: int, delta_in_spacings: float,
                            partial_volumes: bool = True) -> int:
    """Half-bonds of an interior particle of a cubic lattice: the memory estimate the
    scene validator makes before allocating (bytes = this * n * Bonds.resident_bytes)."""
    r = delta_in_spacings + 0.5 if partial_volumes else delta_in_spacings
    k = int(math.ceil(r))
    axis = np.arange(-k, k + 1)
    # Along the last axis the points of each line are counted, not listed: a large horizon
    # (the case this estimate refuses) must not allocate (2k + 1)^3 points in 3D.
    rem = r * r - sum(np.meshgrid(*[axis * axis] * (dim - 1), indexing="ij")).astype(float)
    top = np.floor(np.sqrt(np.maximum(rem, 0.0)))
    for _ in range(2):          # round-off of the square root, either way
        top = np.where(_inside(top * top, rem, partial_volumes), top, top - 1)
        top = np.where(_inside((top + 1) ** 2, rem, partial_volumes), top + 1, top)
    return int(np.sum(np.where(top >= 0, 2 * top + 1, 0))) - 1


def _inside(k2, rem, strict):
    return (k2 < rem) if strict else (k2 <= rem)


def shift_into_box(x0, lo, period) -> np.ndarray:
    """(n, d) whole-period shifts that bring points ``x0`` into the periodic box
    [lo, lo + period) (period 0: that axis is left alone). A search for new bonds among
    reference positions that follow their particles by whole periods brings them in first,
    then adds `periodic_images` (SPB-MPM's conversions)."""
    x0 = np.asarray(x0, dtype=np.float64)
    periodic = np.asarray(period) > 0
    safe = np.where(periodic, period, 1.0)
    return np.where(periodic, -np.floor((x0 - lo) / safe) * safe, 0.0)


def period_shifts(period) -> np.ndarray:
    """Whole-period offsets k * period, k in {-1, 0, 1} along each periodic axis (period >
    0) and 0 along the others: (3^p, d), the zero offset included, in meshgrid order."""
    period = np.asarray(period, dtype=np.float64)
    axes = [(-1, 0, 1) if period[a] > 0 else (0,) for a in range(len(period))]
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(period), -1).T * period


def periodic_images(x0, lo, period, reach):
    """Images of points within ``reach`` of the faces of the periodic box [lo, lo + period)
    (period 0: not periodic). Returns (source rows (m,) int64, shifts (m, d))."""
    x0 = np.asarray(x0, dtype=np.float64)
    dim = x0.shape[1]
    srcs, shifts = [], []
    for shift in period_shifts(period):
        if not shift.any():
            continue
        y = x0 + shift
        inside = np.all((y >= lo - reach) & (y < lo + np.where(period > 0, period, np.inf)
                                             + reach), axis=1)
        rows = np.flatnonzero(inside)
        srcs.append(rows)
        shifts.append(np.broadcast_to(shift, (len(rows), dim)))
    if not srcs:
        return np.empty(0, np.int64), np.empty((0, dim))
    return np.concatenate(srcs).astype(np.int64), np.concatenate(shifts).astype(np.float64)


def _pack_precracks(precracks, dim, periods=None):
    """Pre-cracks as the search kernel reads them: 2D segments (k, 2, 2); 3D polygons as
    vertices and offsets. Along periodic axes (``periods``: lengths, 0 elsewhere) each
    crack also stands one period either way: a bond that crosses the face reaches a
    partner's image, and must meet the crack where that image's bond does (the partner's
    own half-bond, one period away)."""
    seg = np.empty((0, 2, 2))
    poly_v = np.empty((0, 3))
    poly_off = np.zeros(1, dtype=np.int64)
    if precracks is None or len(precracks) == 0:
        return seg, poly_v, poly_off
    shifts = np.zeros((1, dim)) if periods is None else period_shifts(periods)
    if dim == 2:
        one = np.asarray(precracks, dtype=np.float64).reshape(-1, 2, 2)
        seg = np.ascontiguousarray(np.concatenate([one + s for s in shifts]))
    else:
        polys = [np.asarray(p, dtype=np.float64).reshape(-1, 3) + s
                 for s in shifts for p in precracks]
        poly_v = np.ascontiguousarray(np.concatenate(polys))
        poly_off = np.zeros(len(polys) + 1, dtype=np.int64)
        np.cumsum([len(p) for p in polys], out=poly_off[1:])
    return seg, poly_v, poly_off


def _cell_sort(x0, h):
    lo = x0.min(axis=0) if len(x0) else np.zeros(x0.shape[1])
    cell = np.floor((x0 - lo) / h).astype(np.int64)
    ncell = cell.max(axis=0) + 1 if len(x0) else np.ones(x0.shape[1], np.int64)
    keys = np.zeros(len(x0), dtype=np.int64)
    for a in range(x0.shape[1]):
        keys = keys * ncell[a] + cell[:, a]
    order = np.argsort(keys, kind="stable")
    return keys, order.astype(np.int64), lo, ncell.astype(np.int64)


@njit(cache=True, error_model="numpy")
def _lower_bound(a, v):
    lo, hi = 0, len(a)
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, error_model="numpy")
def _search(x0, n_owned, sorted_keys, order, cell_lo, ncell, radius, delta, dx, pv, code,
            seg, poly_v, poly_off, homes, ids, periods, counts, offsets, slot, weight,
            count_only):
    """Cell-list search; first pass counts bonds per owned point, second pass fills them."""
    dim = x0.shape[1]
    r2 = radius * radius
    c = np.empty(3, dtype=np.int64)
    cracks = seg.shape[0] > 0 or len(poly_off) > 1
    # Positions in cell order: the candidates of a row of cells are contiguous in memory.
    xs = np.empty_like(x0)
    for s in range(len(order)):
        for a in range(dim):
            xs[s, a] = x0[order[s], a]
    lo1, hi1 = (-1, 2) if dim == 3 else (0, 1)
    for i in range(n_owned):
        for a in range(dim):
            c[a] = int(math.floor((x0[i, a] - cell_lo[a]) / radius))
        k = 0 if count_only else offsets[i]
        n_i = 0
        # Rows of cells along the last axis are consecutive keys: one search per row.
        for d0 in range(-1, 2):
            for d1 in range(lo1, hi1):
                if dim == 3:
                    ca, cb = c[0] + d0, c[1] + d1
                    if ca < 0 or ca >= ncell[0] or cb < 0 or cb >= ncell[1]:
                        continue
                    row = (ca * ncell[1] + cb) * ncell[2]
                    last = ncell[2]
                else:
                    ca = c[0] + d0
                    if ca < 0 or ca >= ncell[0]:
                        continue
                    row = ca * ncell[1]
                    last = ncell[1]
                cz = c[dim - 1]
                kmin = row + max(cz - 1, 0)
                kmax = row + min(cz + 1, last - 1)
                s = _lower_bound(sorted_keys, kmin)
                e = _lower_bound(sorted_keys, kmax + 1)
                for s in range(s, e):
                    j = order[s]
                    if j == i:
                        continue
                    d2 = 0.0
                    for a in range(dim):
                        t = xs[s, a] - x0[i, a]
                        d2 += t * t
                    if pv:
                        if d2 >= r2:
                            continue
                    elif d2 > r2:
                        continue
                    r = math.sqrt(d2)
                    w = influence(code, r, delta) * partial_volume(r, delta, dx, pv)
                    if w <= 0.0:
                        continue
                    if cracks:
                        px, py, pz, qx, qy, qz = _bond_segment(x0, homes, ids, periods, i, j)
                        if _crosses_precrack(px, py, pz, qx, qy, qz, dim, seg, poly_v,
                                             poly_off):
                            continue
                    if not count_only:
                        slot[k] = j
                        weight[k] = w
                        k += 1
                    n_i += 1
        if count_only:
            counts[i] = n_i


# A point within this fraction of the lengths involved from a line lies on it (`_side`).
ON_LINE = 1e-12


@njit(cache=True, error_model="numpy")
def _side(ax, ay, bx, by, cx, cy):
    """Which side of the line a -> b the point c lies on: the orientation (b - a) x (c - a),
    or 0 when c lies on the line to within ON_LINE of |b - a| |c - a| (L1 lengths). Lattices
    put crack ends exactly on bond lines (a notch tip midway between two rows), where the
    orientation is round-off of either sign: decided so, a tie would depend on where the
    scene sits in space (measured: Kalthoff-Winkler shifted by (0.37, -0.53) cut 4 more
    half-bonds)."""
    o = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    scale = (abs(bx - ax) + abs(by - ay)) * (abs(cx - ax) + abs(cy - ay))
    return 0.0 if abs(o) <= ON_LINE * scale else o


@njit(cache=True, error_model="numpy")
def _bond_segment(x0, homes, ids, periods, i, j):
    """The reference segment of the bond i -> j as both its ends write it: from the end with
    the lower id, at its particle's own reference position (``homes``), to the other end's
    own position moved by the bond's whole periods (read from how far each row's x0
    lies from its home: the image a halo or the periodic search made). Each end of a bond
    then tests a pre-crack with the same numbers and the same arithmetic, so a crack end on
    the bond's line (a tie, which round-off decides: Kalthoff-Winkler's notch tips lie on
    lattice diagonals, a crack drawn from a periodic face ends on bonds across it) cuts
    both half-bonds or neither. Returns (px, py, pz, qx, qy, qz); z = 0 in 2D."""
    dim = x0.shape[1]
    r0 = r1 = r2 = 0.0
    for a in range(dim):
        if periods[a] > 0.0:
            r = (math.floor((x0[j, a] - homes[j, a]) / periods[a] + 0.5)
                 - math.floor((x0[i, a] - homes[i, a]) / periods[a] + 0.5))
            if a == 0:
                r0 = r
            elif a == 1:
                r1 = r
            else:
                r2 = r
    lo, hi = i, j
    if ids[j] < ids[i] or (ids[j] == ids[i] and (r0 < 0.0 or (r0 == 0.0 and (
            r1 < 0.0 or (r1 == 0.0 and r2 < 0.0))))):
        lo, hi = j, i                  # a partner's own image: the one a period up
        r0, r1, r2 = -r0, -r1, -r2
    px, py = homes[lo, 0], homes[lo, 1]
    qx, qy = homes[hi, 0], homes[hi, 1]
    pz = qz = 0.0
    if periods[0] > 0.0:
        qx = qx + r0 * periods[0]
    if periods[1] > 0.0:
        qy = qy + r1 * periods[1]
    if dim == 3:
        pz, qz = homes[lo, 2], homes[hi, 2]
        if periods[2] > 0.0:
            qz = qz + r2 * periods[2]
    return px, py, pz, qx, qy, qz


@njit(cache=True, error_model="numpy")
def _plane_side(nx, ny, nz, ox, oy, oz, px, py, pz):
    """Which side of the plane through o with normal n the point p lies on: n . (p - o), or 0
    within ON_LINE of |n| |p - o| (L1 lengths), as `_side` in 2D: an end on a polygon's
    plane is not across it, so a lattice plane on the crack's plane is not decided by
    round-off."""
    d = nx * (px - ox) + ny * (py - oy) + nz * (pz - oz)
    norm = abs(nx) + abs(ny) + abs(nz)
    return 0.0 if abs(d) <= ON_LINE * norm * (abs(px - ox) + abs(py - oy) + abs(pz - oz)) else d


@njit(cache=True, error_model="numpy")
def _crosses_precrack(px, py, pz, qx, qy, qz, dim, seg, poly_v, poly_off):
    """True when the reference segment p -> q (`_bond_segment`) crosses a pre-crack: a 2D
    segment (the bond's ends strictly on opposite sides of its line, the crack's ends not
    strictly on the same side of the bond's line) or a 3D planar polygon (ends strictly on
    opposite sides of its plane, the crossing point inside the polygon by the even-odd
    rule)."""
    if dim == 2:
        for s in range(seg.shape[0]):
            ax, ay, bx, by = seg[s, 0, 0], seg[s, 0, 1], seg[s, 1, 0], seg[s, 1, 1]
            if _side(ax, ay, bx, by, px, py) * _side(ax, ay, bx, by, qx, qy) < 0.0 and \
               _side(px, py, qx, qy, ax, ay) * _side(px, py, qx, qy, bx, by) <= 0.0:
                return True
        return False
    for g in range(len(poly_off) - 1):
        a0, a1 = poly_off[g], poly_off[g + 1]
        # Newell normal of the polygon.
        nx = ny = nz = 0.0
        for k in range(a0, a1):
            kn = k + 1 if k + 1 < a1 else a0
            nx += (poly_v[k, 1] - poly_v[kn, 1]) * (poly_v[k, 2] + poly_v[kn, 2])
            ny += (poly_v[k, 2] - poly_v[kn, 2]) * (poly_v[k, 0] + poly_v[kn, 0])
            nz += (poly_v[k, 0] - poly_v[kn, 0]) * (poly_v[k, 1] + poly_v[kn, 1])
        ox, oy, oz = poly_v[a0, 0], poly_v[a0, 1], poly_v[a0, 2]
        dp = _plane_side(nx, ny, nz, ox, oy, oz, px, py, pz)
        dq = _plane_side(nx, ny, nz, ox, oy, oz, qx, qy, qz)
        if not dp * dq < 0.0:
            continue
        t = dp / (dp - dq)
        hit0 = px + t * (qx - px)
        hit1 = py + t * (qy - py)
        hit2 = pz + t * (qz - pz)
        # Project on the plane of the two axes where the normal is smallest.
        ax_, ay_, az_ = abs(nx), abs(ny), abs(nz)
        if ax_ >= ay_ and ax_ >= az_:
            u, v, iu, iv = hit1, hit2, 1, 2
        elif ay_ >= az_:
            u, v, iu, iv = hit0, hit2, 0, 2
        else:
            u, v, iu, iv = hit0, hit1, 0, 1
        inside = False
        for k in range(a0, a1):
            kn = k + 1 if k + 1 < a1 else a0
            uk, vk = poly_v[k, iu], poly_v[k, iv]
            un, vn = poly_v[kn, iu], poly_v[kn, iv]
            # A crossing on an edge (to within ON_LINE) is inside: the polygon is closed, as
            # a 2D crack's end cuts the bonds through it (a lattice puts edges on them).
            eu, ev, wu, wv = un - uk, vn - vk, u - uk, v - vk
            if abs(eu * wv - ev * wu) <= ON_LINE * (abs(eu) + abs(ev)) * (abs(wu) + abs(wv)):
                along = eu * wu + ev * wv
                length2 = eu * eu + ev * ev
                if -ON_LINE * length2 <= along <= (1.0 + ON_LINE) * length2:
                    return True
            if (vk > v) != (vn > v):
                if u < uk + (v - vk) * (un - uk) / (vn - vk):
                    inside = not inside
        if inside:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _label_images(offsets, slot, x0, period, image):
    """Each half-bond's periodic image label (bonds.image_label) from its reference offset."""
    X = np.empty(x0.shape[1])
    for i in range(len(offsets) - 1):
        for b in range(offsets[i], offsets[i + 1]):
            for a in range(x0.shape[1]):
                X[a] = x0[slot[b], a] - x0[i, a]
            image[b] = image_label(X, period)


@njit(cache=True, error_model="numpy")
def _sort_segments_by_id(offsets, partner, slot, weight, image):
    """Order each particle's half-bonds by partner id, then image label (the summation order
    on any rank; labels are below 27, so partner * 32 + label orders both)."""
    for i in range(len(offsets) - 1):
        a, b = offsets[i], offsets[i + 1]
        if b - a < 2:
            continue
        o = np.argsort(partner[a:b] * 32 + image[a:b])
        p = partner[a:b][o].copy()
        s = slot[a:b][o].copy()
        w = weight[a:b][o].copy()
        g = image[a:b][o].copy()
        partner[a:b] = p
        slot[a:b] = s
        weight[a:b] = w
        image[a:b] = g

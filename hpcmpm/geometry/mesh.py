"""Mesh bodies: read with meshio, filled with particles by an inside test.

3D: a closed triangle surface (signed crossings along x-lines, the solid-angle winding number
where a line grazes an edge) or a tetrahedral volume mesh (point in any tetrahedron); 2D: a
triangle mesh (point in any triangle).
"""

from __future__ import annotations

import functools
import math
import warnings
from pathlib import Path

import numpy as np
from numba import njit


class MeshError(Exception):
    """A mesh file cannot be read or holds no usable cells."""


def load_mesh(path: Path, dim: int) -> tuple[np.ndarray, tuple[str, np.ndarray]]:
    """Points (n, dim) and (cell kind, connectivity) of the first usable cell block: tetra
    before triangle in 3D (a volume mesh may also carry its boundary triangles).

    Read once per file version: the samplers test a body chunk by chunk."""
    try:
        stat = Path(path).stat()
        version = (stat.st_mtime_ns, stat.st_size)
    except OSError:
        version = None
    return _load_mesh(str(path), dim, version)


@functools.lru_cache(maxsize=8)
def _load_mesh(path: str, dim: int, version) -> tuple[np.ndarray, tuple[str, np.ndarray]]:
    import meshio

    try:
        with warnings.catch_warnings():
            # meshio's STL format sniffing overflows harmlessly on ASCII files.
            warnings.simplefilter("ignore", RuntimeWarning)
            mesh = meshio.read(str(path))
    except Exception as exc:  # meshio raises many types; the user needs one line
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise MeshError(f"cannot read mesh {path}: {first}") from None
    kinds = ("tetra", "triangle") if dim == 3 else ("triangle",)
    for kind in kinds:
        for block in mesh.cells:
            if block.type == kind and len(block.data):
                points = np.ascontiguousarray(np.asarray(mesh.points, np.float64)[:, :dim])
                cells = np.asarray(block.data, np.int64)
                points.setflags(write=False)  # shared by every caller through the cache
                cells.setflags(write=False)
                return points, (kind, cells)
    found = ", ".join(sorted({b.type for b in mesh.cells})) or "none"
    raise MeshError(f"mesh {path} has no {' or '.join(kinds)} cells (found: {found})")


@njit(cache=True)
def _winding_number(px, py, pz, pts, tri):
    """Generalised winding number of a closed triangle surface at a point,
    ``sum_t Omega_t / 4 pi``, with each triangle's solid angle by van Oosterom & Strackee
    (1983): ``tan(Omega / 2) = a.(b x c) / (|a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|)``.
    +-1 inside (by orientation), 0 outside, with no special cases at edges or vertices."""
    total = 0.0
    for t in range(tri.shape[0]):
        i, j, k = tri[t, 0], tri[t, 1], tri[t, 2]
        ax, ay, az = pts[i, 0] - px, pts[i, 1] - py, pts[i, 2] - pz
        bx, by, bz = pts[j, 0] - px, pts[j, 1] - py, pts[j, 2] - pz
        cx, cy, cz = pts[k, 0] - px, pts[k, 1] - py, pts[k, 2] - pz
        la = math.sqrt(ax * ax + ay * ay + az * az)
        lb = math.sqrt(bx * bx + by * by + bz * bz)
        lc = math.sqrt(cx * cx + cy * cy + cz * cz)
        triple = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
               + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la)
        total += 2.0 * math.atan2(triple, den)
    return total / (4.0 * math.pi)


@njit(cache=True)
def _inside_surface(x, line_y, line_z, order, starts, pts, tri, lo_yz, hi_yz, eps, out):
    """Inside test of a closed triangle surface for points grouped on lines parallel to x.

    Each line (line_y, line_z) meets the surface at a few x; a point's winding number is the
    sum of the crossing orientations (sign of the projected triangle's area) beyond it, so a
    line costs one pass over the triangles instead of one per point. A line that passes
    within ``eps`` of a projected edge or vertex (where a crossing could count twice or not
    at all, e.g. on the diagonal of a split cube face) falls back to the solid-angle winding
    number of each of its points, which has no such cases. ``order[starts[l]:starts[l+1]]``
    are the points of line l; lo_yz/hi_yz the triangles' (y, z) bounding boxes."""
    n_tri = tri.shape[0]
    cross_x = np.empty(n_tri)
    cross_sign = np.empty(n_tri)
    for line in range(line_y.shape[0]):
        py, pz = line_y[line], line_z[line]
        count = 0
        degenerate = False
        for t in range(n_tri):
            if py < lo_yz[t, 0] or py > hi_yz[t, 0] or pz < lo_yz[t, 1] or pz > hi_yz[t, 1]:
                continue
            a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
            ay, az = pts[a, 1] - py, pts[a, 2] - pz
            by, bz = pts[b, 1] - py, pts[b, 2] - pz
            cy, cz = pts[c, 1] - py, pts[c, 2] - pz
            d1 = ay * bz - az * by
            d2 = by * cz - bz * cy
            d3 = cy * az - cz * ay
            if abs(d1) <= eps or abs(d2) <= eps or abs(d3) <= eps:
                if (d1 >= -eps and d2 >= -eps and d3 >= -eps) or \
                        (d1 <= eps and d2 <= eps and d3 <= eps):
                    degenerate = True
                    break
                continue
            if (d1 > 0) != (d2 > 0) or (d2 > 0) != (d3 > 0):
                continue
            det = d1 + d2 + d3
            # x of the triangle's plane on the line, by barycentric weights.
            cross_x[count] = (d2 * pts[a, 0] + d3 * pts[b, 0] + d1 * pts[c, 0]) / det
            cross_sign[count] = 1.0 if det > 0 else -1.0
            count += 1
        for q in range(starts[line], starts[line + 1]):
            p = order[q]
            if degenerate:
                w = _winding_number(x[p, 0], py, pz, pts, tri)
            else:
                w = 0.0
                for k in range(count):
                    if cross_x[k] > x[p, 0]:
                        w += cross_sign[k]
            out[p] = abs(w) > 0.5


@njit(cache=True)
def _inside_triangles(x, pts, cells, out):
    """Point in any triangle (2D) by barycentric coordinates, boundaries included."""
    tol = 1e-12
    for p in range(x.shape[0]):
        out[p] = False
        for t in range(cells.shape[0]):
            a, b, c = cells[t, 0], cells[t, 1], cells[t, 2]
            e0x, e0y = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1]
            e1x, e1y = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1]
            rx, ry = x[p, 0] - pts[a, 0], x[p, 1] - pts[a, 1]
            det = e0x * e1y - e0y * e1x
            if det == 0.0:
                continue
            u = (rx * e1y - ry * e1x) / det
            v = (e0x * ry - e0y * rx) / det
            if u >= -tol and v >= -tol and u + v <= 1.0 + tol:
                out[p] = True
                break


@njit(cache=True)
def _inside_tetrahedra(x, pts, cells, out):
    """Point in any tetrahedron (3D): barycentric coordinates by Cramer's rule with the edge
    vectors e1, e2, e3 from vertex 0, boundaries included."""
    tol = 1e-12
    for p in range(x.shape[0]):
        out[p] = False
        for t in range(cells.shape[0]):
            a = cells[t, 0]
            b, c, d = cells[t, 1], cells[t, 2], cells[t, 3]
            e1x, e1y, e1z = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1], pts[b, 2] - pts[a, 2]
            e2x, e2y, e2z = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1], pts[c, 2] - pts[a, 2]
            e3x, e3y, e3z = pts[d, 0] - pts[a, 0], pts[d, 1] - pts[a, 1], pts[d, 2] - pts[a, 2]
            rx, ry, rz = x[p, 0] - pts[a, 0], x[p, 1] - pts[a, 1], x[p, 2] - pts[a, 2]
            # det[e1 e2 e3] = e1 . (e2 x e3); replacing a column by r gives each coordinate.
            det = (e1x * (e2y * e3z - e2z * e3y) + e1y * (e2z * e3x - e2x * e3z)
                   + e1z * (e2x * e3y - e2y * e3x))
            if det == 0.0:
                continue
            u = (rx * (e2y * e3z - e2z * e3y) + ry * (e2z * e3x - e2x * e3z)
                 + rz * (e2x * e3y - e2y * e3x)) / det
            v = (e1x * (ry * e3z - rz * e3y) + e1y * (rz * e3x - rx * e3z)
                 + e1z * (rx * e3y - ry * e3x)) / det
            w = (e1x * (e2y * rz - e2z * ry) + e1y * (e2z * rx - e2x * rz)
                 + e1z * (e2x * ry - e2y * rx)) / det
            if u >= -tol and v >= -tol and w >= -tol and u + v + w <= 1.0 + tol:
                out[p] = True
                break


def inside_mesh(x: np.ndarray, params: dict, dim: int) -> np.ndarray:
    """Mask of points ``x`` (n, dim) inside the (scaled, translated) mesh."""
    points, (kind, cells) = load_mesh(Path(params["file"]), dim)
    points = np.ascontiguousarray(points * params["scale"] + np.asarray(params["translate"]))
    out = np.zeros(len(x), dtype=np.bool_)
    x = np.ascontiguousarray(x, dtype=np.float64)
    if dim == 2:
        _inside_triangles(x, points, cells, out)
    elif kind == "tetra":
        _inside_tetrahedra(x, points, cells, out)
    else:
        _inside_closed_surface(x, points, cells, out)
    return out


def _inside_closed_surface(x: np.ndarray, points: np.ndarray, tri: np.ndarray,
                           out: np.ndarray) -> None:
    """Group the points by their (y, z) line and run the scanline kernel."""
    if len(x) == 0:
        return
    lines, inverse = np.unique(x[:, 1:], axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], np.arange(len(lines) + 1))
    corners = points[tri][:, :, 1:]  # (n_tri, 3 vertices, (y, z))
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    # Edge functions are areas ~ extent^2; within 1e-10 of that a crossing is ambiguous.
    eps = 1e-10 * extent * extent
    _inside_surface(x, np.ascontiguousarray(lines[:, 0]), np.ascontiguousarray(lines[:, 1]),
                    order.astype(np.int64), starts.astype(np.int64), points, tri,
                    np.ascontiguousarray(corners.min(axis=1)),
                    np.ascontiguousarray(corners.max(axis=1)), eps, out)

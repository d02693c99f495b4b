"""Mesh bodies: read with meshio, filled with particles by an inside test.

3D: a closed triangle surface (generalised winding number) or a tetrahedral volume mesh
(point in any tetrahedron); 2D: a triangle mesh (point in any triangle).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
from numba import njit


class MeshError(Exception):
    """A mesh file cannot be read or holds no usable cells."""


def load_mesh(path: Path, dim: int) -> tuple[np.ndarray, tuple[str, np.ndarray]]:
    """Points (n, dim) and (cell kind, connectivity) of the first usable cell block: tetra
    before triangle in 3D (a volume mesh may also carry its boundary triangles)."""
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
                points = np.asarray(mesh.points, dtype=np.float64)[:, :dim]
                return np.ascontiguousarray(points), (kind, np.asarray(block.data, np.int64))
    found = ", ".join(sorted({b.type for b in mesh.cells})) or "none"
    raise MeshError(f"mesh {path} has no {' or '.join(kinds)} cells (found: {found})")


@njit(cache=True)
def _inside_surface(x, pts, tri, out):
    """Generalised winding number of a closed triangle surface, ``sum Omega_t / 4 pi``, with
    the solid angle of each triangle by van Oosterom & Strackee (1983):
    ``tan(Omega / 2) = a.(b x c) / (|a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|)``.
    Unlike ray parity it has no special cases for rays through edges or vertices (lattice
    points often lie on the diagonal of a face split into two triangles); it is 1 inside and
    0 outside, and |w| > 1/2 accepts either orientation."""
    for p in range(x.shape[0]):
        total = 0.0
        for t in range(tri.shape[0]):
            i, j, k = tri[t, 0], tri[t, 1], tri[t, 2]
            ax, ay, az = pts[i, 0] - x[p, 0], pts[i, 1] - x[p, 1], pts[i, 2] - x[p, 2]
            bx, by, bz = pts[j, 0] - x[p, 0], pts[j, 1] - x[p, 1], pts[j, 2] - x[p, 2]
            cx, cy, cz = pts[k, 0] - x[p, 0], pts[k, 1] - x[p, 1], pts[k, 2] - x[p, 2]
            la = math.sqrt(ax * ax + ay * ay + az * az)
            lb = math.sqrt(bx * bx + by * by + bz * bz)
            lc = math.sqrt(cx * cx + cy * cy + cz * cz)
            triple = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
                   + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la)
            total += 2.0 * math.atan2(triple, den)
        out[p] = abs(total) > 2.0 * math.pi


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
        _inside_surface(x, points, cells, out)
    return out

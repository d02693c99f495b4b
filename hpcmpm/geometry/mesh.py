"""Mesh bodies: read with meshio, filled with particles by an inside test.

3D: a closed triangle surface (ray parity along +x) or a tetrahedral volume mesh (point in
any tetrahedron); 2D: a triangle mesh (point in any triangle).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit


class MeshError(Exception):
    """A mesh file cannot be read or holds no usable cells."""


def load_mesh(path: Path, dim: int) -> tuple[np.ndarray, tuple[str, np.ndarray]]:
    """Points (n, dim) and (cell kind, connectivity) of the first usable cell block."""
    import meshio

    try:
        mesh = meshio.read(str(path))
    except Exception as exc:  # meshio raises many types; the user needs one line
        raise MeshError(f"cannot read mesh {path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
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
    """Ray parity along +x against a closed triangle surface."""
    for p in range(x.shape[0]):
        px, py, pz = x[p, 0], x[p, 1], x[p, 2]
        crossings = 0
        for t in range(tri.shape[0]):
            a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
            ay, az = pts[a, 1] - py, pts[a, 2] - pz
            by, bz = pts[b, 1] - py, pts[b, 2] - pz
            cy, cz = pts[c, 1] - py, pts[c, 2] - pz
            # Does the ray's (y, z) point lie in the triangle's projection? Half-open edge
            # rules (sign >= 0 vs > 0) count a ray through a shared edge exactly once.
            d1 = ay * bz - az * by
            d2 = by * cz - bz * cy
            d3 = cy * az - cz * ay
            if not ((d1 >= 0 and d2 >= 0 and d3 >= 0) or (d1 < 0 and d2 < 0 and d3 < 0)):
                continue
            det = d1 + d2 + d3
            if det == 0.0:
                continue
            # x of the triangle plane at (py, pz) by barycentric weights.
            xt = (d2 * pts[a, 0] + d3 * pts[b, 0] + d1 * pts[c, 0]) / det
            if xt > px:
                crossings += 1
        out[p] = crossings % 2 == 1


@njit(cache=True)
def _inside_simplices(x, pts, cells, out):
    """Point in any triangle (2D) or tetrahedron (3D) by barycentric coordinates."""
    dim = x.shape[1]
    tol = -1e-12
    for p in range(x.shape[0]):
        out[p] = False
        for t in range(cells.shape[0]):
            if dim == 2:
                a, b, c = cells[t, 0], cells[t, 1], cells[t, 2]
                e0x, e0y = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1]
                e1x, e1y = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1]
                rx, ry = x[p, 0] - pts[a, 0], x[p, 1] - pts[a, 1]
                det = e0x * e1y - e0y * e1x
                if det == 0.0:
                    continue
                u = (rx * e1y - ry * e1x) / det
                v = (e0x * ry - e0y * rx) / det
                if u >= tol and v >= tol and u + v <= 1 - tol:
                    out[p] = True
                    break
            else:
                a = cells[t, 0]
                m = np.empty((3, 3))
                for k in range(3):
                    for d in range(3):
                        m[d, k] = pts[cells[t, k + 1], d] - pts[a, d]
                r0 = x[p, 0] - pts[a, 0]
                r1 = x[p, 1] - pts[a, 1]
                r2 = x[p, 2] - pts[a, 2]
                det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                       - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                       + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
                if det == 0.0:
                    continue
                # Cramer's rule for the barycentric coordinates.
                u = (r0 * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                     - m[0, 1] * (r1 * m[2, 2] - m[1, 2] * r2)
                     + m[0, 2] * (r1 * m[2, 1] - m[1, 1] * r2)) / det
                v = (m[0, 0] * (r1 * m[2, 2] - m[1, 2] * r2)
                     - r0 * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                     + m[0, 2] * (m[1, 0] * r2 - r1 * m[2, 0])) / det
                w = (m[0, 0] * (m[1, 1] * r2 - r1 * m[2, 1])
                     - m[0, 1] * (m[1, 0] * r2 - r1 * m[2, 0])
                     + r0 * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det
                if u >= tol and v >= tol and w >= tol and u + v + w <= 1 - tol:
                    out[p] = True
                    break


def inside_mesh(x: np.ndarray, params: dict, dim: int) -> np.ndarray:
    """Mask of points ``x`` (n, dim) inside the (scaled, translated) mesh."""
    points, (kind, cells) = load_mesh(Path(params["file"]), dim)
    points = np.ascontiguousarray(points * params["scale"] + np.asarray(params["translate"]))
    out = np.zeros(len(x), dtype=np.bool_)
    x = np.ascontiguousarray(x, dtype=np.float64)
    if dim == 3 and kind == "triangle":
        _inside_surface(x, points, cells, out)
    else:
        _inside_simplices(x, points, cells, out)
    return out

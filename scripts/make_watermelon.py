"""Write inputs/meshes/watermelon_rind.obj and watermelon_flesh.obj: closed triangle surfaces
of a watermelon centred at the origin for watermelon_3d.toml. The flesh is a sphere of radius
R - t (outward normals); the rind is the shell between R and R - t: the outer sphere with
outward normals plus the flesh's very triangles turned inward, so the winding-number fill
(hpcmpm/geometry) puts each lattice point in exactly one of the two bodies (a shell and a
sphere of their own would tile the faceted inner surface differently).

Usage: python scripts/make_watermelon.py [R t n_lat out_dir]   (defaults: R = 0.064,
t = 0.01, 24 latitude bands and 48 meridians: chord error R (1 - cos(pi/48)) = R/470, far
below the scene's particle spacing R/16).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path


def sphere(r: float, n_lat: int) -> tuple[list, list]:
    """UV sphere: vertices and triangles (0-based, counter-clockwise seen from outside)."""
    n_lon = 2 * n_lat
    verts = [(0.0, 0.0, r)]
    for i in range(1, n_lat):
        th = math.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * math.pi * j / n_lon
            verts.append((r * math.sin(th) * math.cos(ph), r * math.sin(th) * math.sin(ph),
                          r * math.cos(th)))
    verts.append((0.0, 0.0, -r))
    south = len(verts) - 1
    ring = lambda i, j: 1 + (i - 1) * n_lon + j % n_lon  # noqa: E731
    tris = []
    for j in range(n_lon):
        tris.append((0, ring(1, j), ring(1, j + 1)))
        tris.append((south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            tris.append((a, c, d))
            tris.append((a, d, b))
    return verts, tris


def write(path: Path, comment: str, verts, tris) -> None:
    with open(path, "w") as f:
        f.write(f"# {comment} (scripts/make_watermelon.py)\n")
        f.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in tris)


def main(argv: list[str]) -> None:
    R = float(argv[0]) if argv else 0.064
    t = float(argv[1]) if len(argv) > 1 else 0.01
    n_lat = int(argv[2]) if len(argv) > 2 else 24
    out = Path(argv[3]) if len(argv) > 3 else Path("inputs/meshes")
    out.mkdir(parents=True, exist_ok=True)
    inner_v, inner_t = sphere(R - t, n_lat)
    outer_v, outer_t = sphere(R, n_lat)
    write(out / "watermelon_flesh.obj", f"sphere R = {R - t:g}", inner_v, inner_t)
    k = len(outer_v)
    shell_t = outer_t + [(a + k, c + k, b + k) for a, b, c in inner_t]   # inner turned inward
    write(out / "watermelon_rind.obj", f"shell {R - t:g} < r < {R:g}", outer_v + inner_v,
          shell_t)


if __name__ == "__main__":
    main(sys.argv[1:])

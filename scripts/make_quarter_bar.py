"""Write inputs/meshes/quarter_bar.obj: a closed, outward-oriented triangle surface of the
quarter (x >= 0, y >= 0) of a cylinder of radius R and length L along z from z = 0, for the
Taylor-bar scene (taylor_cu_3d.toml: symmetry planes x = 0 and y = 0).

Usage: python scripts/make_quarter_bar.py [R L segments out]   (defaults: Wilkins & Guinan
1973, R = 3.81 mm, L = 23.47 mm, 48 arc segments; the chord error R (1 - cos(pi/4/48)) is
R/7500, far below any particle spacing).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path


def quarter_bar(R: float, L: float, segments: int) -> tuple[list, list]:
    """Vertices and triangles (0-based, counter-clockwise seen from outside)."""
    arc = [(R * math.cos(0.5 * math.pi * k / segments), R * math.sin(0.5 * math.pi * k / segments))
           for k in range(segments + 1)]
    verts = [(0.0, 0.0, 0.0), (0.0, 0.0, L)]  # the axis ends: 0 bottom, 1 top
    bottom = [len(verts) + k for k in range(segments + 1)]
    verts += [(x, y, 0.0) for x, y in arc]
    top = [len(verts) + k for k in range(segments + 1)]
    verts += [(x, y, L) for x, y in arc]
    tris = []
    for k in range(segments):
        tris.append((0, bottom[k + 1], bottom[k]))  # bottom cap, normal -z
        tris.append((1, top[k], top[k + 1]))  # top cap, normal +z
        # curved side, normal outward (radial)
        tris.append((bottom[k], bottom[k + 1], top[k + 1]))
        tris.append((bottom[k], top[k + 1], top[k]))
    # plane y = 0 (arc start, k = 0 at (R, 0)): normal -y
    tris.append((0, bottom[0], top[0]))
    tris.append((0, top[0], 1))
    # plane x = 0 (arc end at (0, R)): normal -x
    tris.append((0, 1, top[-1]))
    tris.append((0, top[-1], bottom[-1]))
    return verts, tris


def main(argv: list[str]) -> None:
    R = float(argv[0]) if argv else 3.81e-3
    L = float(argv[1]) if len(argv) > 1 else 23.47e-3
    segments = int(argv[2]) if len(argv) > 2 else 48
    out = Path(argv[3]) if len(argv) > 3 else Path("inputs/meshes/quarter_bar.obj")
    verts, tris = quarter_bar(R, L, segments)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w") as f:
        f.write(f"# quarter cylinder R = {R:g} m, L = {L:g} m (scripts/make_quarter_bar.py)\n")
        f.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in tris)


if __name__ == "__main__":
    main(sys.argv[1:])

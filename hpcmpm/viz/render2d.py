"""2D pictures: each particle a filled disk of its spacing (dx / particles_per_cell) in data
units, true aspect ratio, the domain box, the colliders where they are at the frame's time.

Particles are one matplotlib ``EllipseCollection`` (sizes in data units, one draw call), so
no Python loop runs per particle.
"""

from __future__ import annotations

import numpy as np

from .layout import Canvas, ColourScale, frame_title
from .series import RunGeometry

COLLIDER_FACE, COLLIDER_EDGE = "0.75", "0.25"


class Renderer2D:
    """Draws frames of one run into a fixed canvas; ``draw`` returns the (H, W, 3) picture."""

    def __init__(self, geometry: RunGeometry, scale: ColourScale, size: tuple[int, int]):
        from matplotlib.patches import Rectangle

        self.geometry = geometry
        self.scale = scale
        self.canvas = Canvas(size, scale, geometry.name)
        ax = self.canvas.view
        lo, hi = geometry.lower[:2], geometry.upper[:2]
        pad = 0.02 * float(np.max(hi - lo))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal", adjustable="box", anchor="C")
        ax.add_patch(Rectangle(tuple(lo), *(hi - lo), fill=False, edgecolor="black",
                               linewidth=1.0, zorder=3))
        self._artists: list = []

    def draw(self, x: np.ndarray, values: np.ndarray, time: float) -> np.ndarray:
        from matplotlib.collections import EllipseCollection

        for artist in self._artists:
            artist.remove()
        ax = self.canvas.view
        d = np.full(len(x), self.geometry.spacing)
        disks = EllipseCollection(d, d, np.zeros(len(x)), units="xy", offsets=x[:, :2],
                                  offset_transform=ax.transData, cmap=self.scale.cmap,
                                  norm=self.scale.norm, linewidths=0, zorder=2)
        disks.set_array(np.asarray(values, dtype=np.float64))
        ax.add_collection(disks, autolim=False)
        self._artists = [disks] + [ax.add_patch(p) for p in collider_patches(
            self.geometry, time, float(np.max(self.geometry.upper - self.geometry.lower)))]
        self.canvas.set_title(frame_title(self.geometry.name, time))
        return self.canvas.rgb()


def collider_patches(geometry: RunGeometry, time: float, reach: float) -> list:
    """Matplotlib patches of the colliders active at ``time`` (2D: disks, boxes, half-planes)."""
    from matplotlib.patches import Circle, Polygon

    style = dict(facecolor=COLLIDER_FACE, edgecolor=COLLIDER_EDGE, linewidth=1.0, alpha=0.8,
                 zorder=1)
    patches = []
    for collider in geometry.colliders:
        if not collider.active(time):
            continue
        centre = collider.position(time)[:2]
        R = collider.rotation(time)
        if collider.spec.shape == "sphere":
            patches.append(Circle(tuple(centre), collider.size[0], **style))
        elif collider.spec.shape == "box":
            h = collider.size[:2]
            corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * h
            patches.append(Polygon(centre + corners @ R[:2, :2].T, closed=True, **style))
        elif collider.spec.shape == "half_space":
            # The obstacle is (x - point) . normal <= 0: a large polygon the axes clip.
            normal = R[:2, 2] / np.linalg.norm(R[:2, 2])
            tangent = np.array([-normal[1], normal[0]])
            far = 4 * reach
            corners = [centre + far * tangent, centre - far * tangent,
                       centre - far * tangent - far * normal, centre + far * tangent - far * normal]
            patches.append(Polygon(np.array(corners), closed=True, **style))
    return patches

"""3D pictures: each particle a lit sphere of its spacing, seen through a pinhole camera.

A numba kernel splats the spheres into a z-buffer, nearest first (depth-sorted, so hidden
pixels are rejected before they are shaded), at twice the output resolution; each covered
pixel takes the depth of the sphere's surface there and Blinn-Phong shading (ambient + diffuse
+ a small specular highlight) from a light above the camera's left shoulder. The image is
averaged down 2x2 (anti-aliasing, a second kernel) and laid into the picture's view over the domain box's
edges, drawn with matplotlib beneath it, so particles hide the edges behind them. Sphere
colliders are splatted in grey with the particles; box and cylinder colliders are drawn as
edges.

Default camera: looking at the domain's centre from the front, right and above (relative to
the "up" axis, opposite to gravity, else z), far enough that the domain's bounding sphere
fits the vertical field of view (30 degrees). ``--camera 'eye=X,Y,Z;target=X,Y,Z;up=X,Y,Z;fov=DEG'`` sets
any of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from ..scene import unit_vector
from .layout import Canvas, ColourScale, frame_title
from .series import RenderError, RunGeometry

SUPERSAMPLE = 2
AMBIENT, SPECULAR, SHININESS = 0.35, 0.25, 24.0
# Towards the light, in camera coordinates (x right, y up, z into the picture).
LIGHT = np.array([-0.45, 0.6, -0.66])
COLLIDER_RGB = (0.72, 0.72, 0.72)


def _unit(v: np.ndarray, name: str) -> np.ndarray:
    """v / |v| for any representable v (`unit_vector`: an up of 1e-200 and an eye - target
    of 1e200 were reported as an 'up' parallel to the view)."""
    if not np.all(np.isfinite(v)):
        raise RenderError(f"--camera: {name} overflows; give eye and target within the "
                          f"floating-point range of each other")
    unit = unit_vector(v)
    if unit is None:
        raise RenderError(f"--camera: {name} is the zero vector")
    return np.array(unit)


@dataclass(frozen=True)
class Camera:
    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov: float = 30.0  # vertical field of view, degrees

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors of the camera frame."""
        with np.errstate(over="ignore"):  # `_unit` reports an overflow in one line
            forward = _unit(self.target - self.eye, "target - eye")
        right = np.cross(forward, _unit(self.up, "up"))
        if np.linalg.norm(right) < 1e-12:
            raise RenderError("--camera: 'up' is parallel to the viewing direction")
        right /= np.linalg.norm(right)
        return right, np.cross(right, forward), forward

    def project(self, points: np.ndarray, width: int, height: int):
        """Pixel coordinates (column, row from the top), depth along the view axis and the
        focal length in pixels of ``points`` (n, 3) in a ``width`` x ``height`` image."""
        right, up, forward = self.basis()
        q = np.asarray(points, dtype=np.float64) - self.eye
        depth = q @ forward
        focal = 0.5 * height / math.tan(math.radians(self.fov) / 2)
        safe = np.where(depth > 1e-12, depth, np.nan)
        col = 0.5 * width + focal * (q @ right) / safe
        row = 0.5 * height - focal * (q @ up) / safe
        return col, row, depth, focal


def default_camera(lower: np.ndarray, upper: np.ndarray, up_axis: int,
                   fov: float = 30.0) -> Camera:
    centre = 0.5 * (lower + upper)
    radius = 0.5 * float(np.linalg.norm(upper - lower))
    up_axis %= 3  # -1 (RunGeometry without a scene): the last axis
    up = np.zeros(3)
    up[up_axis] = 1.0
    across, depth_axis = [a for a in range(3) if a != up_axis]
    direction = 0.55 * np.eye(3)[across] - 0.85 * np.eye(3)[depth_axis] + 0.5 * up
    direction /= np.linalg.norm(direction)
    # The bounding sphere fits the vertical field of view, with 10 % to spare: perspective
    # makes the near corners reach a little beyond the sphere's outline.
    distance = 1.1 * radius / math.sin(math.radians(fov) / 2)
    return Camera(centre + distance * direction, centre, up, fov)


def parse_camera(spec: str | None, default: Camera) -> Camera:
    """``eye=X,Y,Z;target=X,Y,Z;up=X,Y,Z;fov=DEG``, any subset, over ``default``."""
    if not spec:
        return default
    changes = {}
    for part in spec.replace(" ", "").split(";"):
        if not part:
            continue
        key, _, value = part.partition("=")
        try:
            if key in ("eye", "target", "up"):
                vector = np.array([float(s) for s in value.split(",")])
                if vector.shape != (3,) or not np.all(np.isfinite(vector)):
                    raise ValueError
                changes[key] = vector
            elif key == "fov":
                changes[key] = float(value)
                if not 1.0 <= changes[key] <= 150.0:
                    raise ValueError
            else:
                raise RenderError(f"--camera {spec!r}: unknown key {key!r}; "
                                  f"use eye=X,Y,Z;target=X,Y,Z;up=X,Y,Z;fov=DEG")
        except ValueError:
            raise RenderError(f"--camera {spec!r}: {key} needs "
                              f"{'degrees in 1..150' if key == 'fov' else 'three numbers X,Y,Z'}"
                              ) from None
    camera = replace(default, **changes)
    if np.array_equal(camera.target, camera.eye):
        raise RenderError(f"--camera {spec!r}: eye and target are the same point")
    camera.basis()
    return camera


@njit(cache=True)
def splat_spheres(col, row, depth, radius_px, radius, rgb, light, halfway, image, zbuf):
    """Shade spheres into ``image`` (H, W, >= 3) with depth test against ``zbuf`` (H, W).

    Particles must come nearest first. Sphere p covers the pixels within ``radius_px[p]`` of
    (col, row); at offset (a, b) / radius_px the surface normal in camera coordinates is
    (a, -b, -sqrt(1 - a^2 - b^2)) and its depth depth[p] - radius[p] sqrt(1 - a^2 - b^2)."""
    height, width = zbuf.shape
    for p in range(col.shape[0]):
        r = radius_px[p]
        if not (depth[p] > 0.0 and r > 0.0):
            continue
        i0 = max(int(math.floor(col[p] - r)), 0)
        i1 = min(int(math.ceil(col[p] + r)), width - 1)
        j0 = max(int(math.floor(row[p] - r)), 0)
        j1 = min(int(math.ceil(row[p] + r)), height - 1)
        for j in range(j0, j1 + 1):
            b = (j + 0.5 - row[p]) / r
            for i in range(i0, i1 + 1):
                a = (i + 0.5 - col[p]) / r
                q = a * a + b * b
                if q >= 1.0:
                    continue
                nz = math.sqrt(1.0 - q)
                z = depth[p] - radius[p] * nz
                if z >= zbuf[j, i]:
                    continue
                zbuf[j, i] = z
                diffuse = max(0.0, a * light[0] - b * light[1] - nz * light[2])
                spec = max(0.0, a * halfway[0] - b * halfway[1] - nz * halfway[2]) ** SHININESS
                shade = AMBIENT + (1.0 - AMBIENT) * diffuse
                for c in range(3):
                    image[j, i, c] = min(1.0, rgb[p, c] * shade + SPECULAR * spec)


@njit(cache=True)
def downsample(image, zbuf, s, out):
    """``out`` (h, w, 4) RGBA from the s x s blocks of ``image`` (s h, s w, 3): alpha is the
    covered fraction (``zbuf`` finite), colour the mean over the covered pixels, so edges are
    anti-aliased against whatever lies beneath."""
    h, w = out.shape[:2]
    for j in range(h):
        for i in range(w):
            r = g = b = 0.0
            covered = 0
            for jj in range(j * s, j * s + s):
                for ii in range(i * s, i * s + s):
                    if zbuf[jj, ii] < np.inf:
                        covered += 1
                        r += image[jj, ii, 0]
                        g += image[jj, ii, 1]
                        b += image[jj, ii, 2]
            if covered:
                out[j, i, 0] = r / covered
                out[j, i, 1] = g / covered
                out[j, i, 2] = b / covered
            else:
                out[j, i, 0] = out[j, i, 1] = out[j, i, 2] = 1.0
            out[j, i, 3] = covered / (s * s)


class Renderer3D:
    """Draws frames of one run into a fixed canvas; ``draw`` returns the (H, W, 3) picture."""

    def __init__(self, geometry: RunGeometry, scale: ColourScale, size: tuple[int, int],
                 camera: Camera):
        self.geometry = geometry
        self.scale = scale
        self.camera = camera
        self.canvas = Canvas(size, scale, geometry.name)
        _, _, self.w, self.h = self.canvas.view_px
        self.overlay = self.canvas.figure.add_axes(self.canvas.view.get_position(), zorder=2)
        for ax in (self.canvas.view, self.overlay):
            ax.set_axis_off()
            ax.set_xlim(0, self.w)
            ax.set_ylim(self.h, 0)
        self.canvas.view.set_zorder(0)
        self._segments(box_edges(geometry.lower, geometry.upper), "0.35", 0, self.canvas.view)
        light = LIGHT / np.linalg.norm(LIGHT)
        halfway = light + np.array([0.0, 0.0, -1.0])
        self.light, self.halfway = light, halfway / np.linalg.norm(halfway)
        self._artists: list = []
        self._buffers = None

    def pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(column, row) of world points in the view's pixels (origin: its top-left corner)."""
        col, row, _, _ = self.camera.project(points, self.w, self.h)
        return col, row

    def _segments(self, segments: np.ndarray, colour, zorder: int, ax):
        from matplotlib.collections import LineCollection

        if len(segments) == 0:
            return None
        col, row = self.pixels(segments.reshape(-1, 3))
        lines = LineCollection(np.stack([col, row], axis=1).reshape(-1, 2, 2), colors=colour,
                               linewidths=0.8, zorder=zorder)
        return ax.add_collection(lines, autolim=False)

    def draw(self, x: np.ndarray, values: np.ndarray, time: float) -> np.ndarray:
        for artist in self._artists:
            artist.remove()
        rgb = self.scale.rgba(values)[:, :3]
        radius = np.full(len(x), 0.5 * self.geometry.spacing)
        spheres, edges = collider_shapes(self.geometry, time)
        if spheres:
            centres, radii = np.array([s[0] for s in spheres]), np.array([s[1] for s in spheres])
            x = np.concatenate([x, centres])
            radius = np.concatenate([radius, radii])
            rgb = np.concatenate([rgb, np.tile(COLLIDER_RGB, (len(spheres), 1))])
        image = self.raster(x, radius, rgb)
        left, bottom, _, _ = self.canvas.view_px
        # Placed pixel for pixel (no resampling), above the view's box edges and below the
        # overlay that holds the colliders' edges.
        self._artists = [self.canvas.figure.figimage(image, left, bottom, origin="upper",
                                                     zorder=1)]
        lines = self._segments(edges, "0.25", 2, self.overlay)
        if lines is not None:
            self._artists.append(lines)
        self.canvas.set_title(frame_title(self.geometry.name, time))
        return self.canvas.rgb()

    def raster(self, x: np.ndarray, radius: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        """RGBA (h, w, 4) of the spheres, transparent where none is."""
        s = SUPERSAMPLE
        W, H = self.w * s, self.h * s
        col, row, depth, focal = self.camera.project(x, W, H)
        visible = np.isfinite(col) & (depth > 0)
        order = np.argsort(np.where(visible, depth, np.inf), kind="stable")
        order = order[visible[order]]
        if self._buffers is None:  # reused: allocating them was a third of a frame's time
            self._buffers = (np.empty((H, W, 3), dtype=np.float32),
                             np.empty((H, W), dtype=np.float32))
        image, zbuf = self._buffers
        zbuf.fill(np.inf)
        splat_spheres(col[order], row[order], depth[order], focal * radius[order] / depth[order],
                      radius[order], np.ascontiguousarray(rgb[order], dtype=np.float64),
                      self.light, self.halfway, image, zbuf)
        out = np.empty((self.h, self.w, 4), dtype=np.float32)
        downsample(image, zbuf, s, out)
        return out


def box_edges(lower: np.ndarray, upper: np.ndarray, rotation: np.ndarray | None = None,
              centre: np.ndarray | None = None) -> np.ndarray:
    """The 12 edges (12, 2, 3) of an axis-aligned box, or of a box with half extents
    ``upper`` about ``centre`` turned by ``rotation``."""
    corners = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=float)
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    if rotation is None:
        points = lower + corners * (upper - lower)
    else:
        points = centre + ((2 * corners - 1) * upper) @ rotation.T
    return np.array([[points[a], points[b]] for a, b in pairs])


def collider_shapes(geometry: RunGeometry, time: float) -> tuple[list, np.ndarray]:
    """Sphere colliders as (centre, radius) and box/cylinder colliders as edges (m, 2, 3)."""
    spheres, edges = [], []
    for collider in geometry.colliders:
        if not collider.active(time):
            continue
        centre = collider.position(time)
        R = collider.rotation(time)
        if collider.spec.shape == "sphere":
            spheres.append((centre, float(collider.size[0])))
        elif collider.spec.shape == "box":
            edges.append(box_edges(None, collider.size, R, centre))
        elif collider.spec.shape == "cylinder":
            edges.append(cylinder_edges(centre, R, collider.size[0], collider.size[1]))
    return spheres, (np.concatenate(edges) if edges else np.zeros((0, 2, 3)))


def cylinder_edges(centre, R, radius, half_length, segments: int = 32) -> np.ndarray:
    angle = np.linspace(0, 2 * np.pi, segments + 1)
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(angle)], 1)
    out = []
    for z in (-half_length, half_length):
        points = centre + (ring + [0, 0, z]) @ R.T
        out.append(np.stack([points[:-1], points[1:]], axis=1))
    quarter = ring[: segments: segments // 4]
    ends = [centre + (quarter + [0, 0, z]) @ R.T for z in (-half_length, half_length)]
    out.append(np.stack(ends, axis=1))
    return np.concatenate(out)

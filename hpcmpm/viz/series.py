"""A run's frames as the renderer and the plotter see them: listed in ``particles.xdmf`` order,
read one at a time, with the scene geometry (domain, particle spacing, colliders) they carry.

A run still being written is read as it stands: the frames its ``particles.xdmf`` names and
that exist on disk (a frame file is renamed into place only once complete, docs/output.md).
"""

from __future__ import annotations

import json
import math
import re
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HpcmpmError
from ..io.xdmf import FRAME_PATTERN, XDMF_NAME


class RenderError(HpcmpmError):
    """A render or plot request the run cannot satisfy (no frames, unknown field, bad range)."""

    exit_code = 2


@dataclass(frozen=True)
class FrameRef:
    """One frame file of a run: its number (``frame_NNNNNN``), path and time."""

    index: int
    path: Path
    time: float


def list_frames(run_dir) -> list[FrameRef]:
    """The run's frames in the order of its ``particles.xdmf`` (missing files left out).

    Without an XDMF file (a folder of copied frames) the frame files are taken in number order,
    their times read from the files."""
    run_dir = Path(run_dir)
    if run_dir.is_file():
        raise RenderError(f"{run_dir}: a file, not a run folder; give the folder that holds "
                          f"the run's frames ({run_dir.parent}), and --frames to pick some")
    if not run_dir.is_dir():
        raise RenderError(f"{run_dir}: no such run folder")
    xdmf = run_dir / XDMF_NAME
    frames = []
    if xdmf.exists():
        try:
            root = ET.parse(xdmf).getroot()
        except ET.ParseError as exc:
            raise RenderError(f"{xdmf}: not readable XDMF ({exc})") from None
        for grid in root.iter("Grid"):
            if grid.get("GridType") != "Uniform":
                continue
            item = grid.find("Geometry/DataItem")
            time = grid.find("Time")
            if item is None or time is None:
                continue
            name = Path(item.text.strip().split(":")[0]).name
            match = FRAME_PATTERN.match(name)
            if match and (run_dir / name).exists():
                frames.append(FrameRef(int(match.group(1)), run_dir / name,
                                       float(time.get("Value"))))
    else:
        for path in sorted(run_dir.glob("frame_*.h5")):
            match = FRAME_PATTERN.match(path.name)
            if match:
                frames.append(FrameRef(int(match.group(1)), path, _time_of(path)))
    if not frames:
        raise RenderError(f"{run_dir}: no frames (frame_*.h5 named in {XDMF_NAME}) to read")
    return frames


def _time_of(path: Path) -> float:
    import h5py

    with h5py.File(path, "r") as h5:
        return float(h5.attrs["time"])


FRAMES_HELP = ("A:B:K, a Python slice of the frames in particles.xdmf order "
               "(e.g. -1 the last, ::10 every tenth, 5:20)")


def select_frames(frames: list, spec: str | None) -> list:
    """The frames picked by ``spec``: ``A:B:K`` (a Python slice over the list), or ``A``."""
    if spec is None or spec.strip() in ("", ":", "::"):
        return list(frames)
    parts = spec.split(":")
    if len(parts) > 3:
        raise RenderError(f"--frames {spec!r}: expected {FRAMES_HELP}")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise RenderError(f"--frames {spec!r}: expected integers in {FRAMES_HELP}") from None
    if len(values) == 1:
        i = values[0]
        if not -len(frames) <= i < len(frames):
            raise RenderError(f"--frames {spec!r}: no such frame, the run has {len(frames)} "
                              f"(0..{len(frames) - 1})")
        return [frames[i]]
    if len(values) == 3 and values[2] == 0:
        raise RenderError(f"--frames {spec!r}: the step K must not be 0")
    picked = frames[slice(*values)]
    if not picked:
        raise RenderError(f"--frames {spec!r} selects none of the run's {len(frames)} frames")
    return picked


def read_frame_data(path: Path, names=None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Datasets of ``/particles`` (all, or those in ``names`` that exist) and root attributes."""
    import h5py

    with h5py.File(path, "r") as h5:
        group = h5["particles"]
        wanted = list(group) if names is None else [n for n in names if n in group]
        data = {n: group[n][...] for n in wanted}
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
    return data, attrs


def dataset_shapes(path: Path) -> dict[str, tuple[int, ...]]:
    import h5py

    with h5py.File(path, "r") as h5:
        return {name: tuple(d.shape) for name, d in h5["particles"].items()}


@dataclass
class RunGeometry:
    """What a picture of the run needs besides the particles: from the frames' scene text."""

    name: str
    dim: int
    lower: np.ndarray
    upper: np.ndarray
    spacing: float
    material_names: list[str] = field(default_factory=list)
    colliders: list = field(default_factory=list)  # hpcmpm.boundaries.colliders.Collider
    up_axis: int = -1  # opposite to gravity; -1: the last axis


def run_geometry(frame: FrameRef, run_dir: Path, x: np.ndarray) -> RunGeometry:
    """Domain, particle spacing, material names and colliders of the run, from the scene text
    stored in ``frame``; where the text is missing or not a valid scene, the domain is the
    particles' bounding box and the spacing the mean spacing of the points."""
    import h5py

    with h5py.File(frame.path, "r") as h5:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
    dim = int(attrs.get("dim", x.shape[1]))
    name = _scene_name(attrs, run_dir)
    scene = _parse(attrs.get("scene", ""))
    if scene is not None:
        from ..boundaries.colliders import Collider

        gravity = np.asarray(scene.gravity, dtype=float)
        up = int(np.argmax(np.abs(gravity))) if np.any(gravity) else dim - 1
        return RunGeometry(name, dim, np.asarray(scene.domain_lo, float),
                           np.asarray(scene.domain_hi, float),
                           scene.dx / scene.particles_per_cell,
                           [m.name for m in scene.materials],
                           [Collider(c, dim) for c in scene.colliders], up)
    lower, upper = (x.min(axis=0), x.max(axis=0)) if len(x) else (np.zeros(dim), np.ones(dim))
    extent = np.maximum(upper - lower, 1e-12)
    spacing = float(np.prod(extent) / max(len(x), 1)) ** (1.0 / dim)
    pad = 0.5 * spacing
    return RunGeometry(name, dim, lower - pad, upper + pad, spacing)


def _parse(text: str):
    from ..scene import parse_scene

    if not text:
        return None
    try:
        return parse_scene(text)
    except (HpcmpmError, tomllib.TOMLDecodeError, OSError, ValueError, KeyError):
        return None


def _scene_name(attrs: dict, run_dir: Path) -> str:
    """The scene file's stem (first entry of the restart chain), else the run folder's name."""
    try:
        chain = json.loads(attrs.get("restart_chain", "[]"))
    except (TypeError, ValueError):
        chain = []
    for entry in chain:
        if str(entry).endswith(".toml"):
            return Path(entry).stem
    return Path(run_dir).resolve().name


# The smallest picture: at its smallest font the layout (layout.Canvas) takes 56 pixels of
# the width (margins, colour bar, tick labels) and 22 of the height (title, margin), so 96 x
# 64 leaves a view of 40 x 42. Below about 60 x 26 the view had no pixels and matplotlib
# raised (the former bound, 16, let a traceback through).
MIN_SIZE = (96, 64)
MAX_SIZE = 8192
# Frames per second of a movie: a GIF frame lasts a whole number of milliseconds (1000 fps
# at most), and a frame of more than 100 s is no movie.
FPS_RANGE = (0.01, 1000.0)


def parse_size(spec: str) -> tuple[int, int]:
    """``WxH`` in pixels, within MIN_SIZE..MAX_SIZE."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", spec or "")
    if not match:
        raise RenderError(f"--size {spec!r}: expected WxH in pixels, e.g. 960x720")
    w, h = int(match.group(1)), int(match.group(2))
    if not (MIN_SIZE[0] <= w <= MAX_SIZE and MIN_SIZE[1] <= h <= MAX_SIZE):
        raise RenderError(f"--size {spec!r}: width must be {MIN_SIZE[0]}..{MAX_SIZE} and "
                          f"height {MIN_SIZE[1]}..{MAX_SIZE} pixels")
    return w, h


def check_fps(fps: float) -> None:
    """A movie's frame rate within FPS_RANGE (0, a negative or a NaN rate failed only at
    the movie, after every frame was drawn)."""
    if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
        raise RenderError(f"--fps {fps:g}: must be {FPS_RANGE[0]:g}..{FPS_RANGE[1]:g} "
                          f"frames per second")


def finite_range(values: np.ndarray) -> tuple[float, float]:
    """(min, max) of the finite values; (inf, -inf) when there are none."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return math.inf, -math.inf
    return float(finite.min()), float(finite.max())

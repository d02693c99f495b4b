"""``hpcmpm render RUN_DIR``: one PNG per frame and a movie of them.

Under ``mpiexec -n N`` the frames are dealt round-robin to the ranks (each renders and writes
its own PNGs); rank 0 lists the frames, and encodes the movie once every rank is done. The
colour scale is fixed over all rendered frames (min and max reduced over ranks), so colours
mean the same in every picture.
"""

from __future__ import annotations

import logging
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import HpcmpmError
from .fields import FieldChoice, datasets_needed, field_values, parse_field
from .layout import colour_scale
from .movie import write_movie
from .series import (FrameRef, RenderError, check_fps, dataset_shapes, finite_range, list_frames,
                     read_frame_data, run_geometry, select_frames)

log = logging.getLogger(__name__)
DEFAULT_SIZE = (960, 720)


@dataclass
class RenderResult:
    pngs: list[Path]
    movie: Path | None
    seconds_per_frame: float  # wall time of the slowest rank / the frames it drew


def render_run(run_dir, field: str | None = None, frames: str | None = None, out=None,
               size: tuple[int, int] = DEFAULT_SIZE, camera: str | None = None,
               fps: float = 12.0, movie: str = "auto", comm=None,
               quiet: bool = True) -> RenderResult:
    """Render the frames of ``run_dir`` picked by ``frames`` (A:B:K) coloured by ``field``.

    ``out`` defaults to ``RUN_DIR/render``; PNGs are ``render_NNNNNN.png`` (the frame's
    number), the movie ``render.mp4`` (or ``.gif``) when more than one frame is rendered."""
    check_fps(fps)
    if comm is None:
        from ..parallel import Communicator

        comm = Communicator()
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else run_dir / "render"
    choice = parse_field(field)
    plan = _on_root(comm, lambda: _plan(run_dir, choice, frames))
    picked, needed, indices = plan
    mine = picked[comm.rank::comm.size]

    def colour_range():
        lo, hi = np.inf, -np.inf
        for ref in mine:
            data, attrs = read_frame_data(ref.path, needed)
            a, b = finite_range(field_values(choice, data, int(attrs["dim"])))
            lo, hi = min(lo, a), max(hi, b)
        return lo, hi

    lo, hi = _everywhere(comm, colour_range)
    lo, hi = comm.min(lo), comm.max(hi)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_pictures(out, indices)
    comm.barrier()

    def draw_mine():
        first, _ = read_frame_data(picked[0].path, ["x"])
        geometry = run_geometry(picked[0], run_dir, first["x"])
        renderer = _renderer(geometry, colour_scale(choice, lo, hi, geometry.material_names),
                             size, camera)
        from tqdm import tqdm

        start = time.perf_counter()
        bar = tqdm(mine, unit="frame", file=sys.stderr, disable=quiet or comm.rank != 0 or
                   len(picked) < 2, desc=f"render ({comm.size} rank{'s' * (comm.size > 1)})")
        for ref in bar:
            data, attrs = read_frame_data(ref.path, ["x", *needed])
            values = field_values(choice, data, geometry.dim)
            _save_png(renderer.draw(data["x"], values, float(attrs["time"])), png_path(out, ref))
        return (time.perf_counter() - start) / max(len(mine), 1)

    seconds = comm.max(_everywhere(comm, draw_mine))
    pngs = [png_path(out, ref) for ref in picked]
    movie_path = None
    if len(picked) > 1:
        movie_path = _on_root(comm, lambda: write_movie(pngs, out / "render", fps, movie))
    return RenderResult(pngs, movie_path, seconds)


def _plan(run_dir: Path, choice: FieldChoice, frames: str | None):
    every = list_frames(run_dir)
    picked = select_frames(every, frames)
    return (picked, datasets_needed(choice, dataset_shapes(picked[0].path)),
            {ref.index for ref in every})


PNG_NAME = re.compile(r"^render_(\d{6,})\.png$")


def remove_stale_pictures(out: Path, indices: set[int]) -> list[Path]:
    """Delete the ``render_NNNNNN.png`` in ``out`` of frames the run no longer has (a run
    replaced with ``--force`` or restarted earlier had more); returns them. Pictures of
    frames that exist stay, rendered this time or not."""
    stale = [p for p in out.iterdir()
             if (m := PNG_NAME.match(p.name)) and int(m.group(1)) not in indices]
    for p in stale:
        p.unlink()
    return stale


def _renderer(geometry, scale, size, camera):
    if geometry.dim == 2:
        from .render2d import Renderer2D

        if camera:
            raise RenderError("--camera applies to 3D runs only")
        return Renderer2D(geometry, scale, size)
    from .render3d import Renderer3D, default_camera, parse_camera

    default = default_camera(geometry.lower, geometry.upper, geometry.up_axis)
    return Renderer3D(geometry, scale, size, parse_camera(camera, default))


def png_path(out: Path, ref: FrameRef) -> Path:
    return out / f"render_{ref.index:06d}.png"


def _save_png(rgb: np.ndarray, path: Path) -> None:
    from PIL import Image

    tmp = path.with_name(path.name + ".tmp")
    Image.fromarray(rgb).save(tmp, format="PNG")
    tmp.replace(path)


def _on_root(comm, work):
    """``work()`` on rank 0; every rank gets its result or raises its error (decide together)."""
    result, error = None, None
    if comm.rank == 0:
        try:
            result = work()
        except HpcmpmError as exc:
            error = exc
    result, error = comm.bcast((result, error))
    if error is not None:
        raise error
    return result


def _everywhere(comm, work):
    """``work()`` on every rank; if any rank fails, every rank raises the first error."""
    result, error = None, None
    try:
        result = work()
    except HpcmpmError as exc:
        error = exc
    except (OSError, KeyError) as exc:
        error = RenderError(f"cannot read a frame: {exc}")
    errors = [e for e in comm.allgather(error) if e is not None]
    if errors:
        raise errors[0]
    return result


def render_command(args) -> int:
    """The CLI verb: prints where the pictures and the movie went (rank 0)."""
    from ..parallel import Communicator
    from .series import parse_size

    comm = Communicator()
    size = parse_size(args.size) if args.size else DEFAULT_SIZE
    result = render_run(args.run_dir, args.field, args.frames, args.out, size, args.camera,
                        args.fps, args.movie, comm, quiet=args.quiet)
    if comm.rank == 0:
        folder = result.pngs[0].parent
        print(f"rendered {len(result.pngs)} frame(s) into {folder}/render_*.png "
              f"({result.seconds_per_frame:.3g} s a frame per rank, {comm.size} rank(s))")
        if result.movie is not None:
            print(f"movie: {result.movie.resolve()}")
    return 0

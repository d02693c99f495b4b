"""A movie of rendered frames: MP4 (H.264) through ffmpeg when one is available, else an
animated GIF (or WebP) through Pillow.

ffmpeg comes from the ``imageio-ffmpeg`` wheel (installed by scripts/install.sh: it ships a
static ffmpeg, so no root is needed) or from ``ffmpeg`` on PATH.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .series import RenderError

FORMATS = ("auto", "mp4", "gif", "webp", "none")


def find_ffmpeg() -> str | None:
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def write_movie(pngs: list[Path], stem: Path, fps: float, fmt: str = "auto") -> Path | None:
    """Encode ``pngs`` (in order) into ``stem``.mp4 (or .gif/.webp); returns the movie's path,
    or None for ``fmt = "none"``."""
    if fmt not in FORMATS:
        raise RenderError(f"--movie {fmt!r}: choose one of {', '.join(FORMATS)}")
    if fmt == "none" or not pngs:
        return None
    if fmt in ("auto", "mp4"):
        ffmpeg = find_ffmpeg()
        if ffmpeg is not None:
            return _mp4(ffmpeg, pngs, stem.with_suffix(".mp4"), fps)
        if fmt == "mp4":
            raise RenderError("--movie mp4: no ffmpeg found (pip install imageio-ffmpeg, or put "
                              "ffmpeg on PATH); --movie gif needs none")
        fmt = "gif"
    return _animated(pngs, stem.with_suffix(f".{fmt}"), fps)


def _frames(pngs: Iterable[Path]):
    from PIL import Image

    for path in pngs:
        with Image.open(path) as image:
            yield np.asarray(image.convert("RGB"))


def _mp4(ffmpeg: str, pngs: list[Path], path: Path, fps: float) -> Path:
    first = next(_frames(pngs[:1]))
    height, width = first.shape[:2]
    # yuv420p (what every player decodes) needs even sizes: pad by one pixel where odd.
    command = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{width}x{height}", "-r", f"{fps:g}", "-i", "-",
               "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2:color=white", "-c:v", "libx264",
               "-pix_fmt", "yuv420p", "-crf", "20", "-movflags", "+faststart", str(path)]
    proc = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for frame in _frames(pngs):
            if frame.shape[:2] != (height, width):
                raise RenderError(f"movie: frames differ in size ({frame.shape[1]}x"
                                  f"{frame.shape[0]} after {width}x{height})")
            proc.stdin.write(np.ascontiguousarray(frame).tobytes())
        proc.stdin.close()
    except (BrokenPipeError, RenderError):
        proc.kill()
        proc.wait()
        raise
    error = proc.stderr.read().decode(errors="replace")
    if proc.wait() != 0:
        raise RenderError(f"movie: ffmpeg failed: {error.strip().splitlines()[-1:] or '?'}")
    return path


def _animated(pngs: list[Path], path: Path, fps: float) -> Path:
    from PIL import Image

    images = (Image.fromarray(frame) for frame in _frames(pngs))
    first = next(images)
    first.save(path, save_all=True, append_images=images, duration=round(1000 / fps), loop=0)
    return path


def movie_frame_count(path: Path) -> int:
    """Frames in a movie written by `write_movie` (MP4 counted by decoding with ffmpeg)."""
    path = Path(path)
    if path.suffix == ".mp4":
        import imageio_ffmpeg

        return imageio_ffmpeg.count_frames_and_secs(str(path))[0]
    from PIL import Image

    with Image.open(path) as image:
        return image.n_frames

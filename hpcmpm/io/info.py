"""``hpcmpm info FILE.h5``: what a frame or checkpoint holds, and whether a checkpoint verifies."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import h5py

from ..errors import CheckpointError, HpcmpmError


class OutputFileError(HpcmpmError):
    """A file given to ``hpcmpm info`` is missing or is not an hpcmpm frame or checkpoint."""

    exit_code = 6


def scene_name(scene_text: str, scene_path: str | None = None) -> str:
    """The scene's ``name`` (top level or ``[scene]``), else its file stem, else "(unnamed)"."""
    try:
        table = tomllib.loads(scene_text or "")
    except tomllib.TOMLDecodeError:
        table = {}
    for candidate in (table.get("name"), (table.get("scene") or {}).get("name")
                      if isinstance(table.get("scene"), dict) else None):
        if isinstance(candidate, str) and candidate:
            return candidate
    if scene_path and scene_path != "<checkpoint>":
        return Path(scene_path).stem
    return "(unnamed)"


def provenance(chain: list[str]) -> str:
    """The run's history from its restart chain (the scene file, then each checkpoint it was
    restarted from): "run of S, not restarted" or "run of S, restarted from A, then B"."""
    if not chain:
        return "unknown"
    first, restarts = chain[0], chain[1:]
    if not restarts:
        return f"run of {first}, not restarted"
    return f"run of {first}, restarted from {', then '.join(restarts)}"


def _text(value: Any) -> Any:
    return value.decode() if isinstance(value, bytes) else value


def describe(path) -> list[str]:
    """The lines ``hpcmpm info`` prints for ``path``; raises `OutputFileError`."""
    path = Path(path)
    if not path.exists():
        raise OutputFileError(f"{path}: no such file")
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise OutputFileError(f"{path}: not a readable HDF5 file "
                              f"({' '.join(str(exc).split())})") from None
    with h5:
        attrs = {k: _text(v) for k, v in h5.attrs.items()}
        kind = attrs.get("kind")
        if kind not in ("frame", "checkpoint") or "particles" not in h5:
            raise OutputFileError(f"{path}: not an hpcmpm frame or checkpoint")
        meta = json.loads(attrs.get("meta", "{}")) if kind == "checkpoint" else {}
        chain = json.loads(attrs.get("restart_chain", "[]") or "[]")
        # Where the scene came from: a checkpoint's meta, a frame's attribute, or (frames
        # written before they carried it) the scene file that starts the provenance chain.
        scene_path = meta.get("scene_path") or attrs.get("scene_path") or \
            next((c for c in chain[:1] if c.endswith(".toml")), None)
        lines = [
            f"file:        {path}",
            f"kind:        {kind}",
            f"scene:       {scene_name(attrs.get('scene', ''), scene_path)}",
            f"time:        {float(attrs.get('time', 0.0)):.9g}",
            f"step:        {int(attrs.get('step', 0))}",
            f"dim:         {int(attrs.get('dim', 0))}",
            f"particles:   {int(attrs.get('n_particles', 0))}",
            f"ranks:       {int(attrs.get('n_ranks', 0))} (written in {attrs.get('io_mode', '?')}"
            f" mode)",
            f"version:     hpcmpm {attrs.get('hpcmpm_version', '?')}",
        ]
        if chain:
            lines.append(f"provenance:  {provenance(chain)}")
        if kind == "frame":
            lines.append(f"frame:       {int(attrs.get('frame_index', 0))}")
        lines.append("datasets:")
        h5.visititems(lambda name, obj: lines.append(
            f"  /{name:<22} {str(obj.shape):<16} {obj.dtype}")
            if isinstance(obj, h5py.Dataset) else None)
    if kind == "checkpoint":
        lines.append(f"checksum:    {verify_checkpoint(path)}")
    return lines


def verify_checkpoint(path: Path) -> str:
    """"ok ..." or "FAILED: <what is wrong>", read on this process alone."""
    from .checkpoint import read_checkpoint

    try:
        read_checkpoint(path, _SingleProcess())
    except CheckpointError as exc:
        return f"FAILED: {exc}"
    return "ok (every dataset verifies)"


class _SingleProcess:
    """The Communicator verbs for one process, so `info` needs no MPI launch."""

    rank, size = 0, 1

    def allgather(self, obj):
        return [obj]

    def bcast(self, obj, root=0):
        return obj


def info_command(args) -> int:
    """``hpcmpm info FILE.h5`` (``args.file``): print the summary. A missing or foreign file
    raises `OutputFileError`; a checkpoint that fails verification is printed as such and
    returns `CheckpointError.exit_code`."""
    lines = describe(args.file)
    for line in lines:
        print(line)
    return CheckpointError.exit_code if lines[-1].startswith("checksum:    FAILED") else 0

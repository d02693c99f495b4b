"""``hpcmpm info FILE.h5``: what a frame or checkpoint holds, and whether a checkpoint verifies;
``hpcmpm info RUN_FOLDER``: where a run stands (its frames, its checkpoints, whether it reached
its end time) and the command that continues it."""

from __future__ import annotations

import json
import shlex
import tomllib
from pathlib import Path
from typing import Any

import h5py

from ..errors import CheckpointError, HpcmpmError
from .checkpoint import CKPT_PATTERN
from .xdmf import FRAME_PATTERN


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


def scene_path(attrs: dict[str, Any], meta: dict[str, Any], chain: list[str]) -> str | None:
    """Where a file's scene came from: a checkpoint's meta, a frame's attribute, or (frames
    written before they carried it) the scene file that starts the provenance chain."""
    return meta.get("scene_path") or attrs.get("scene_path") or \
        next((c for c in chain[:1] if c.endswith(".toml")), None)


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
        if CKPT_PATTERN.match(path.name):
            # A checkpoint that cannot be opened (truncated, overwritten) is a checkpoint that
            # fails verification, as `info RUN_FOLDER` and `restart` report it: exit 4.
            return [f"file:        {path}",
                    "kind:        checkpoint (by its name: the file cannot be opened)",
                    f"checksum:    {verify_checkpoint(path)}"]
        raise OutputFileError(f"{path}: not a readable HDF5 file "
                              f"({' '.join(str(exc).split())})") from None
    with h5:
        attrs = {k: _text(v) for k, v in h5.attrs.items()}
        kind = attrs.get("kind")
        if kind not in ("frame", "checkpoint") or "particles" not in h5:
            raise OutputFileError(f"{path}: not an hpcmpm frame or checkpoint")
        meta = json.loads(attrs.get("meta", "{}")) if kind == "checkpoint" else {}
        chain = json.loads(attrs.get("restart_chain", "[]") or "[]")
        lines = [
            f"file:        {path}",
            f"kind:        {kind}",
            f"scene:       {scene_name(attrs.get('scene', ''), scene_path(attrs, meta, chain))}",
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


def _attrs(path: Path) -> dict[str, Any]:
    """A frame's or checkpoint's root attributes (text decoded); {} if it cannot be read."""
    try:
        with h5py.File(path, "r") as h5:
            return {k: _text(v) for k, v in h5.attrs.items()}
    except OSError:
        return {}


def _time(attrs: dict[str, Any]) -> str:
    return f"{float(attrs['time']):.9g}" if "time" in attrs else "?"


def describe_run(folder) -> tuple[list[str], int]:
    """The lines ``hpcmpm info RUN_FOLDER`` prints and its exit code: the frames (count, first
    and last with their times, numbers missing from the series), every checkpoint (step and
    time, from its attributes), the newest one verified (a failure names the previous one and
    exits with `CheckpointError.exit_code`), the end time the newest checkpoint records,
    whether the run reached it, and the command that continues the run. Reads two frames'
    attributes and one checkpoint in full; raises `OutputFileError` for a folder that holds
    neither a frame nor a checkpoint."""
    from .checkpoint import list_checkpoints, reached_end

    folder = Path(folder)
    frames = sorted((int(m.group(1)), p) for p in folder.iterdir()
                    if (m := FRAME_PATTERN.match(p.name)))
    checkpoints = list_checkpoints(folder)
    if not frames and not checkpoints:
        raise OutputFileError(f"{folder}: no frame (frame_NNNNNN.h5) or checkpoint "
                              f"(ckpt_SSSSSSSSS.h5) here: not a run folder")
    newest = checkpoints[-1][1] if checkpoints else None
    last_frame = _attrs(frames[-1][1]) if frames else {}
    # The newest checkpoint's attributes, or the last frame's where it cannot be read.
    source = (_attrs(newest) if newest else {}) or last_frame
    meta = json.loads(source.get("meta", "{}") or "{}")
    chain = json.loads(source.get("restart_chain", "[]") or "[]")
    lines = [f"run:         {folder}",
             f"scene:       {scene_name(source.get('scene', ''), scene_path(source, meta, chain))}"]
    if chain:
        lines.append(f"provenance:  {provenance(chain)}")
    if frames:
        span = f"{frames[-1][1].name} (t = {_time(last_frame)})"
        if len(frames) > 1:
            span = f"{frames[0][1].name} (t = {_time(_attrs(frames[0][1]))}) to {span}"
        lines.append(f"frames:      {len(frames)}: {span}")
        present = {k for k, _ in frames}
        missing = [k for k in range(frames[0][0], frames[-1][0]) if k not in present]
        if missing:
            shown = ", ".join(str(k) for k in missing[:10])
            lines.append(f"             missing from the series: {len(missing)} ({shown}"
                         f"{', ...' if len(missing) > 10 else ''})")
    else:
        lines.append("frames:      none")
    if not checkpoints:
        lines += ["checkpoints: none",
                  "end time:    not recorded (frames do not hold it; a checkpoint does)",
                  "continue:    not possible without a checkpoint; run the scene again"]
        return lines, 0
    for k, (step, path) in enumerate(checkpoints):
        lines.append(f"{'checkpoints:' if k == 0 else '':<13}{path.name} (step {step}, "
                     f"t = {_time(_attrs(path))})")
    verdict = verify_checkpoint(newest)
    lines.append(f"newest:      {newest.name}: {verdict}")
    if verdict.startswith("FAILED"):
        lines.append("continue:    not from the newest checkpoint (above)")
        return lines, CheckpointError.exit_code
    now, end = float(meta.get("time", source.get("time", 0.0))), float(meta["end_time"])
    lines.append(f"end time:    {end:.9g}")
    if reached_end(now, end):
        lines += [f"state:       finished (t = {now:.9g})",
                  f"continue:    hpcmpm restart {shlex.quote(str(folder))} --end-time T "
                  f"(T > {now:.9g})"]
    else:
        lines += [f"state:       stopped at t = {now:.9g}, before its end time",
                  f"continue:    hpcmpm restart {shlex.quote(str(folder))}"]
    return lines, 0


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
    """``hpcmpm info FILE.h5`` or ``hpcmpm info RUN_FOLDER`` (``args.file``): print the
    summary (`describe`, `describe_run`). A missing or foreign file raises `OutputFileError`;
    a checkpoint that fails verification is printed as such and returns
    `CheckpointError.exit_code`."""
    if Path(args.file).is_dir():
        lines, code = describe_run(args.file)
    else:
        lines = describe(args.file)
        code = CheckpointError.exit_code if lines[-1].startswith("checksum:    FAILED") else 0
    for line in lines:
        print(line)
    return code

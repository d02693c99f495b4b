"""Checkpoints: every particle field and the run's state, written atomically, verified on load.

``ckpt_SSSSSSSSS.h5`` (S = step, 9 digits) holds ``/particles/<field>`` for every field of the
ParticleSet (any dtype and shape), rows in rank order (rank 0's particles, then rank 1's, ...,
each rank's in its own order), ``/layout/rank_counts``, and the caller's ``meta``: JSON values in
the root attribute ``meta``, numpy arrays as datasets ``/meta/<key>``. Every dataset carries a
``checksum`` attribute (`hpcmpm.io.checksum`), verified when read.

Writing: ``ckpt_....h5.tmp``, fsync, rename, fsync the folder; only then are checkpoints beyond
the last ``keep`` deleted, so a crash at any moment leaves at least one complete checkpoint.
Reading on the same rank count gives every rank back exactly its rows in its order (a restart
continues bit for bit); on another rank count rank r reads the r-th of ``size`` even contiguous
slices and the caller redistributes them (``Domain.decompose`` / ``migrate``).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .. import __version__
from ..errors import CheckpointError
from . import checksum as cks
from .shared import (DEFAULT_CHUNK_BYTES, SharedFile, attr_value, json_default, resolve_mode,
                     send_rows_in_turn)

CKPT_PATTERN = re.compile(r"^ckpt_(\d+)\.h5$")
FORMAT_VERSION = 1


def checkpoint_name(step: int) -> str:
    return f"ckpt_{int(step):09d}.h5"


def list_checkpoints(path_dir) -> list[tuple[int, Path]]:
    """Complete checkpoints in ``path_dir`` as (step, path), oldest first (``*.tmp`` ignored)."""
    folder = Path(path_dir)
    if not folder.is_dir():
        return []
    found = []
    for path in folder.iterdir():
        match = CKPT_PATTERN.match(path.name)
        if match:
            found.append((int(match.group(1)), path))
    return sorted(found)


def reached_end(time: float, end_time: float) -> bool:
    """Whether a run (or its checkpoint) at ``time`` has reached ``end_time``: the time is a
    sum of steps, so a run lands within round-off of its end."""
    return time >= end_time * (1 - 1e-12)


def latest_checkpoint(path_dir) -> Path | None:
    """The checkpoint with the highest step in ``path_dir``, or None. A file with the final name
    is complete by construction (written as ``*.tmp`` and renamed), so none is opened here; a
    damaged one is reported by `read_checkpoint`, which names the previous one."""
    found = list_checkpoints(path_dir)
    return found[-1][1] if found else None


# -- writing ---------------------------------------------------------------------------------
def split_meta(meta: dict) -> tuple[dict, dict[str, np.ndarray]]:
    """(JSON-able values, numpy arrays) of ``meta``; arrays become datasets."""
    plain, arrays = {}, {}
    for key, value in meta.items():
        if isinstance(value, np.ndarray):
            arrays[key] = value
        else:
            plain[key] = value
    return plain, arrays


def write_checkpoint(path_dir, domain, particles, meta: dict, keep: int = 2,
                     mode: str | None = "auto", chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> Path:
    """Write ``ckpt_<step>.h5`` into ``path_dir`` (collective) and return its path.

    ``meta`` must hold ``step`` and ``time``; rank 0's ``meta`` is the one stored. ``keep``
    newest checkpoints up to this one are kept (older ones deleted after this one is complete);
    checkpoints with a higher step than this one (another timeline) are left alone.
    Raises `CheckpointError` on every rank when the file cannot be written.
    """
    meta = domain.bcast(dict(meta) if domain.rank == 0 else None)
    folder = Path(domain.bcast(str(path_dir) if domain.rank == 0 else None))
    mode = resolve_mode(mode, domain)
    plain, arrays = split_meta(meta)
    try:
        meta_json = json.dumps(plain, default=json_default)
    except TypeError as exc:
        raise CheckpointError(f"checkpoint meta is not JSON serialisable: {exc}") from None
    step = int(meta["step"])
    path = folder / checkpoint_name(step)
    error = None
    if domain.rank == 0:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            error = f"{path}: cannot create the folder {folder}: {exc}"
    error = domain.bcast(error)
    if error:
        raise CheckpointError(error)

    names = particles.field_names()
    rows = {name: np.ascontiguousarray(particles[name]) for name in names}
    counts = np.asarray(domain.allgather(particles.n), dtype=np.int64)
    n_total, offset = int(counts.sum()), int(counts[: domain.rank].sum())
    partials = {name: cks.partial_checksum(rows[name], offset) for name in names}
    sums = {name: cks.combine(p[name] for p in domain.allgather(partials)) for name in names}
    attrs = {
        "kind": "checkpoint", "format": FORMAT_VERSION, "step": step,
        "time": float(meta.get("time", 0.0)), "dim": int(particles.dim),
        "n_particles": n_total, "n_ranks": domain.size, "io_mode": mode,
        "hpcmpm_version": meta.get("hpcmpm_version", __version__),
        "scene": meta.get("scene_text", meta.get("scene", "")),
        "restart_chain": attr_value(list(meta.get("restart_chain", []))),
        "meta": meta_json, "checksum_algorithm": cks.ALGORITHM,
    }
    try:
        out = SharedFile(path, domain, mode, fsync=True)
    except OSError as exc:
        error = f"{path}: cannot create the checkpoint: {exc}"
    if domain.any(error is not None):
        raise CheckpointError(_first([error], domain))
    try:
        out.set_attrs(attrs)
        dsets = {}
        for name in names:
            dsets[name] = out.create(f"particles/{name}", (n_total,) + rows[name].shape[1:],
                                     rows[name].dtype)
            out.set_attrs({"checksum": cks.format_checksum(sums[name])}, f"particles/{name}")
        for key, array in {"layout/rank_counts": counts,
                           **{f"meta/{k}": v for k, v in arrays.items()}}.items():
            out.write_small(key, array)
            out.set_attrs({"checksum": cks.format_checksum(cks.checksum(array))}, key)
        if mode == "mpio":
            starts = np.array([offset] if particles.n else [], dtype=np.int64)
            lengths = np.array([particles.n] if particles.n else [], dtype=np.int64)
            for name in names:
                out.write_runs(dsets[name], starts, lengths, rows[name])
        else:
            def sink(first: int, piece: dict[str, np.ndarray]) -> None:
                for name, arr in piece.items():
                    out.write_rows(dsets[name], first, arr)

            send_rows_in_turn(domain, rows, chunk_bytes, sink)
    except (OSError, ValueError, RuntimeError) as exc:
        out.abandon()
        raise CheckpointError(f"{path}: cannot write the checkpoint: {exc}") from None
    try:
        out.commit()
    except OSError as exc:
        raise CheckpointError(str(exc)) from None
    if domain.rank == 0:
        prune_checkpoints(folder, step, keep)
    domain.barrier()
    return path


def prune_checkpoints(folder: Path, step: int, keep: int) -> None:
    """Delete checkpoints older than the ``keep`` newest up to ``step`` (this one included)."""
    older = [p for s, p in list_checkpoints(folder) if s < step]
    for path in older[: max(0, len(older) - (max(1, keep) - 1))]:
        path.unlink(missing_ok=True)


def _first(errors, domain) -> str:
    found = [e for e in domain.allgather(errors[0]) if e]
    return found[0] if found else "unknown error"


# -- reading ---------------------------------------------------------------------------------
def read_checkpoint(path, domain) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """This rank's share of the particles of checkpoint ``path`` and the stored ``meta``.

    Collective. Same rank count as written: each rank gets its own rows back, in order.
    Otherwise each rank gets an even contiguous slice (the caller migrates them). Every
    dataset's checksum is verified; any problem (missing, truncated or corrupt file) raises
    `CheckpointError` on every rank, naming the file and, where one exists, the previous
    checkpoint."""
    path = Path(path)
    fields, meta, error = {}, {}, None
    partials: dict[str, int] = {}
    expected: dict[str, str] = {}
    try:
        fields, meta, partials, expected = _read_share(path, domain.rank, domain.size)
    except NotACheckpoint as exc:
        error = str(exc)  # complete: it names the checkpoint to use instead
    except CheckpointError as exc:
        error = _with_previous(path, str(exc))
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        error = _with_previous(path, f"{path.name}: cannot be read ({_one_line(exc)})")
    errors = [e for e in domain.allgather(error) if e]
    if errors:
        raise CheckpointError(errors[0])
    gathered = domain.allgather(partials)
    for name, want in expected.items():
        got = cks.format_checksum(cks.combine(p[name] for p in gathered))
        if got != want:
            raise CheckpointError(_with_previous(
                path, f"{path.name}: checksum mismatch in /particles/{name}: file is corrupt"))
    return fields, meta


def _read_share(path: Path, rank: int, size: int):
    if not path.exists():
        raise NotACheckpoint(_missing(path))
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        sizes = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", str(exc))
        if sizes:
            raise CheckpointError(f"{path.name}: file is truncated ({sizes.group(1)} of "
                                  f"{sizes.group(2)} bytes): the write did not finish or the "
                                  f"copy is incomplete") from None
        raise CheckpointError(f"{path.name}: not a readable HDF5 file ({_one_line(exc)})") \
            from None
    with h5:
        kind = h5.attrs.get("kind")
        if kind == "frame":
            raise NotACheckpoint(_checkpoint_for_frame(path, int(h5.attrs.get("step", 0))))
        if kind != "checkpoint":
            raise CheckpointError(f"{path.name}: not an hpcmpm checkpoint")
        n_total = int(h5.attrs["n_particles"])
        counts = _verified(h5, "layout/rank_counts")
        if int(h5.attrs["n_ranks"]) == size and len(counts) == size:
            start, count = int(counts[:rank].sum()), int(counts[rank])
        else:
            base, extra = divmod(n_total, size)
            start, count = rank * base + min(rank, extra), base + (rank < extra)
        fields, partials, expected = {}, {}, {}
        for name, dset in h5["particles"].items():
            if dset.shape[0] != n_total:
                raise CheckpointError(f"{path.name}: /particles/{name} has {dset.shape[0]} rows,"
                                      f" expected {n_total}: file is corrupt")
            fields[name] = dset[start:start + count]
            partials[name] = cks.partial_checksum(fields[name], start)
            expected[name] = _stored_checksum(path, dset)
        meta = json.loads(h5.attrs["meta"])
        if "meta" in h5:
            for key in h5["meta"]:
                meta[key] = _verified(h5, f"meta/{key}")
    return fields, meta, partials, expected


def _verified(h5: h5py.File, name: str) -> np.ndarray:
    array = h5[name][...]
    if cks.format_checksum(cks.checksum(array)) != _stored_checksum(Path(h5.filename), h5[name]):
        raise CheckpointError(f"{Path(h5.filename).name}: checksum mismatch in /{name}: "
                              f"file is corrupt")
    return array


def _stored_checksum(path: Path, dset: h5py.Dataset) -> str:
    value = dset.attrs.get("checksum")
    if value is None:
        raise CheckpointError(f"{path.name}: {dset.name} has no checksum: file is corrupt")
    return value.decode() if isinstance(value, bytes) else str(value)


class NotACheckpoint(CheckpointError):
    """A frame or a missing file given where a checkpoint is needed; the message names the
    checkpoint to use, where there is one."""


def _missing(path: Path) -> str:
    """What to say of a checkpoint path that does not exist: the folder's newest checkpoint
    (a run without checkpoint_every writes only its last), or that the folder is missing."""
    message = f"{path}: no such checkpoint"
    if not path.parent.is_dir():
        return f"{message} (no folder {path.parent})"
    found = list_checkpoints(path.parent)
    if found:
        names = ", ".join(p.name for _, p in found[-3:])
        return f"{message}; {path.parent} holds {names}" + \
            (f" and {len(found) - 3} earlier" if len(found) > 3 else "")
    return f"{message}; {path.parent} holds no checkpoint"


def _checkpoint_for_frame(path: Path, step: int) -> str:
    """What to restart from instead of frame ``path`` (of step ``step``): the newest
    checkpoint of its folder at or before that step."""
    message = f"{path.name}: is a frame, not a checkpoint (restart reads ckpt_*.h5 files)"
    found = list_checkpoints(path.parent)
    before = [p for s, p in found if s <= step]
    if before:
        return f"{message}; the newest checkpoint at or before its step {step} is {before[-1]}"
    if found:
        return (f"{message}; {path.parent} has no checkpoint at or before its step {step} "
                f"(the first is {found[0][1].name})")
    return f"{message}; {path.parent} holds no checkpoint"


def _with_previous(path: Path, message: str) -> str:
    step = CKPT_PATTERN.match(path.name)
    if step is None:  # not named like a checkpoint: "previous" means nothing
        found = list_checkpoints(path.parent)
        if found:
            return f"{message}; the newest checkpoint in {path.parent} is {found[-1][1].name}"
        return f"{message}; there is no checkpoint in {path.parent}"
    earlier = [p for s, p in list_checkpoints(path.parent) if s < int(step.group(1))]
    if earlier:
        return f"{message}; the previous checkpoint {earlier[-1].name} may still be usable"
    return f"{message}; there is no earlier checkpoint in {path.parent}"


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__

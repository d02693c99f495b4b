"""Frames: one HDF5 file per output time, rows sorted by particle id, plus ``particles.xdmf``.

A frame ``frame_NNNNNN.h5`` holds ``/particles/{id, x, v, F, mass, material}`` and the extra
fields the scene asks for, every row one particle, rows in increasing id order whatever the rank
count (a file written on 1 rank and on 64 ranks is the same). Root attributes carry the time,
step, dimension, particle count and provenance (resolved scene text, version, rank count,
restart chain). Layout and modes: docs/output.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import FrameError
from .shared import DEFAULT_CHUNK_BYTES, SharedFile, attr_value, gather_by_id, resolve_mode
from .xdmf import FrameCatalog

# Frame dataset name -> ParticleSet field. `material` is the group (material index). A run
# carries F, or J alone when all its materials are volumetric; whichever it has is written.
CORE_DATASETS = {"id": "id", "x": "x", "v": "v", "F": "F", "J": "J", "mass": "mass",
                 "material": "group"}
DATASET_DTYPES = {"id": np.int64, "material": np.int32}


def frame_name(index: int) -> str:
    return f"frame_{index:06d}.h5"


class FrameWriter:
    """Writes frames of a run into ``out_dir`` and keeps ``particles.xdmf`` in step.

    Parameters
    ----------
    out_dir : folder shared by all ranks (rank 0's path is used on every rank).
    domain : the run's Domain (or any Communicator).
    scene_text : resolved scene TOML, stored in every frame.
    dim : 2 or 3.
    fields : extra particle fields to write besides the core ones (skipped when the
        ParticleSet has no such field).
    provenance : ``restart_chain`` (list of paths: the scene file, then each checkpoint the run
        was restarted from), optionally ``scene_path`` and ``hpcmpm_version``.
    first_frame : number of the first frame this writer writes (a restart continues the count).
    mode : ``"auto"`` (mpio when h5py has MPI and size > 1), ``"serial"`` or ``"mpio"``;
        ``None`` reads ``$HPCMPM_IO_MODE``.
    chunk_bytes : largest piece of rows a rank sends to rank 0 at once in serial mode.
    """

    name = "frames"

    def __init__(self, out_dir, domain, scene_text: str, dim: int, fields: list[str],
                 provenance: dict, first_frame: int = 0, mode: str | None = "auto",
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES):
        self.domain = domain
        self.out_dir = Path(domain.bcast(str(out_dir) if domain.rank == 0 else None))
        if domain.rank == 0:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        domain.barrier()
        self.scene_text = scene_text
        self.dim = int(dim)
        self.fields = [f for f in fields if f not in CORE_DATASETS and f != "group"]
        self.provenance = dict(provenance)
        self.frame_index = int(first_frame)
        self.mode = resolve_mode(mode, domain)
        self.chunk_bytes = int(chunk_bytes)
        self.catalog = FrameCatalog(self.out_dir) if domain.rank == 0 else None

    def write(self, particles, time: float, step: int,
              extra_attrs: dict[str, Any] | None = None,
              derived: dict[str, np.ndarray] | None = None) -> Path:
        """Write the next frame (collective: every rank calls it) and return its path.

        ``derived`` holds per-particle arrays that are not particle fields (rows in the
        particles' order), e.g. the Kirchhoff stress ``tau``; they are written when asked for
        in ``fields``."""
        path = self.out_dir / frame_name(self.frame_index)
        rows = self._rows_sorted_by_id(particles, derived or {})
        ids = rows.pop("id")
        n_total = self.domain.sum(len(ids))
        attrs = {
            "kind": "frame", "time": float(time), "step": int(step), "dim": self.dim,
            "frame_index": self.frame_index, "n_particles": int(n_total),
            "hpcmpm_version": self.provenance.get("hpcmpm_version", __version__),
            "n_ranks": self.domain.size, "io_mode": self.mode, "scene": self.scene_text,
            "scene_path": str(self.provenance.get("scene_path", "")),
            "restart_chain": attr_value(list(self.provenance.get("restart_chain", []))),
        }
        for key, value in (extra_attrs or {}).items():
            attrs.setdefault(key, attr_value(value))

        out = SharedFile(path, self.domain, self.mode)
        try:
            out.set_attrs(attrs)
            dsets = {"id": out.create("particles/id", (n_total,), np.int64)}
            for name, arr in rows.items():
                dsets[name] = out.create(f"particles/{name}", (n_total,) + arr.shape[1:],
                                         arr.dtype)
            out.set_attrs({"dim": self.dim}, group="particles")
            self._fill(out, dsets, ids, rows, n_total)
        except BaseException:
            out.abandon()
            raise
        try:
            out.commit()  # a write failure on any rank is raised here on every rank
        except OSError as exc:
            raise FrameError(f"frame {path.name} not written: {exc}") from None
        if self.catalog is not None:
            shapes = {name: ((n_total,) + arr.shape[1:], arr.dtype.str)
                      for name, arr in {"id": ids, **rows}.items()}
            self.catalog.add(self.frame_index, float(time), self.dim, int(n_total), shapes)
            self.catalog.write()
        self.domain.barrier()
        self.frame_index += 1
        return path

    def _rows_sorted_by_id(self, particles, derived) -> dict[str, np.ndarray]:
        order = np.argsort(particles["id"], kind="stable")
        rows = {}
        for name, field in CORE_DATASETS.items():
            if field not in particles:
                continue  # F or J: the run has one of them
            arr = particles[field][order]
            rows[name] = arr.astype(DATASET_DTYPES[name]) if name in DATASET_DTYPES else arr
        for name in self.fields:
            if name in particles:
                rows[name] = particles[name][order]
            elif name in derived:
                rows[name] = derived[name][order]
        return rows

    def _fill(self, out: SharedFile, dsets, ids, rows, n_total) -> None:
        everything = {"id": ids, **rows}
        dense, first = _dense(self.domain, ids, n_total)
        if self.mode == "mpio" and dense:
            # Ids first..first+N-1: row = id - first, each rank writes its runs in place.
            starts, counts = _runs(ids - first)
            for name, arr in everything.items():
                out.write_runs(dsets[name], starts, counts, arr)
            return

        empty = {k: a[:0] for k, a in everything.items()}

        def sink(first_row: int, piece: dict[str, np.ndarray] | None) -> None:
            # Serial: rank 0 writes the merged piece. mpio with id gaps: rank 0 writes it in a
            # collective write that the other ranks join with an empty selection.
            if out.mode == "serial":
                for name, arr in piece.items() if piece is not None else ():
                    out.write_rows(dsets[name], first_row, arr)
                return
            piece = empty if piece is None else piece
            count = len(piece["id"])
            starts = np.array([first_row] if count else [], dtype=np.int64)
            counts = np.array([count] if count else [], dtype=np.int64)
            for name, arr in piece.items():
                out.write_runs(dsets[name], starts, counts, arr)

        gather_by_id(self.domain, ids, everything, self.chunk_bytes, sink)


def _dense(domain, ids: np.ndarray, n_total: int) -> tuple[bool, int]:
    """(whether the ids are exactly min..max, min). Ids are unique (a ParticleSet invariant),
    so max - min + 1 == N says it."""
    lo = domain.min(int(ids[0]) if len(ids) else np.iinfo(np.int64).max)
    hi = domain.max(int(ids[-1]) if len(ids) else np.iinfo(np.int64).min)
    return n_total == 0 or hi - lo + 1 == n_total, lo


def _runs(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Maximal runs of consecutive integers in the sorted ``rows``: (starts, counts)."""
    if len(rows) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    first = np.concatenate(([0], breaks))
    last = np.concatenate((breaks, [len(rows)]))
    return rows[first].astype(np.int64), (last - first).astype(np.int64)


def read_frame(path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """All datasets of ``/particles`` and the root attributes of a frame file (serial read)."""
    import h5py

    with h5py.File(path, "r") as h5:
        data = {name: h5["particles"][name][...] for name in h5["particles"]}
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()}
    return data, attrs


__all__ = ["FrameWriter", "frame_name", "read_frame"]

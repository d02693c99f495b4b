"""One HDF5 file that every rank contributes rows to: the machinery frames and checkpoints share.

Two write modes, one file layout (docs/output.md):

``mpio``
    h5py built against parallel HDF5 (``h5py.get_config().mpi``): every rank opens the file with
    ``driver="mpio"``, datasets and attributes are created collectively, and each rank writes its
    own rows with one collective hyperslab write. A rank without rows still takes part with an
    empty selection (Dedalus found that a collective write hangs when a rank skips it).
``serial``
    The PyPI h5py (the default install): rank 0 alone opens the file and the other ranks hand it
    their rows in bounded pieces (``chunk_bytes``, 64 MiB by default), so rank 0 never holds the
    whole data set.

Every file is written to ``NAME.tmp`` and renamed by rank 0 once closed (optionally after
fsync), so a file with the final name is always complete. Only `Communicator` verbs are used;
``domain.comm`` is handed to h5py's mpio driver unopened.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np

from ..errors import HpcmpmError

MODES = ("auto", "serial", "mpio")
DEFAULT_CHUNK_BYTES = 64 * 2**20
RUNS_PER_WRITE = 256
# HDF5 1.8 object headers: attributes larger than 64 KiB (a long scene text) need dense
# attribute storage, which the 1.8 file format has; ParaView's HDF5 reads it.
LIBVER = ("v108", "latest")


def mpio_available() -> bool:
    """True when this h5py was built against parallel HDF5."""
    return bool(h5py.get_config().mpi)


def resolve_mode(mode: str | None, domain) -> str:
    """``auto`` -> ``mpio`` when h5py has MPI and there is more than one rank, else ``serial``.

    ``mode=None`` reads ``$HPCMPM_IO_MODE`` (default ``auto``)."""
    mode = mode or os.environ.get("HPCMPM_IO_MODE", "auto")
    if mode not in MODES:
        raise HpcmpmError(f"I/O mode {mode!r}: must be one of {', '.join(MODES)}")
    if mode == "auto":
        return "mpio" if mpio_available() and domain.size > 1 else "serial"
    if mode == "mpio" and not mpio_available():
        raise HpcmpmError("I/O mode 'mpio' needs h5py built with MPI (this is the serial PyPI "
                          "wheel); run scripts/setup_parallel_hdf5.sh or use mode 'serial'")
    return mode


def tmp_name(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def replace_atomically(tmp: Path, path: Path, fsync: bool) -> None:
    """Rename ``tmp`` to ``path``; with ``fsync`` the data and the directory entry reach the disk
    first, so a crash leaves either the old state or the complete new file."""
    if fsync:
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    os.replace(tmp, path)
    if fsync:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_text_atomically(path: Path, text: str) -> None:
    tmp = tmp_name(path)
    tmp.write_text(text, encoding="utf-8")    # XML and scene text: UTF-8, whatever the locale
    os.replace(tmp, path)


def attr_value(value: Any) -> Any:
    """A value h5py stores as an attribute: numbers and strings as they are, the rest as JSON."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, default=json_default)


def json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def rows_per_piece(row_bytes: int, chunk_bytes: int) -> int:
    return max(1, chunk_bytes // max(1, row_bytes))


class SharedFile:
    """An HDF5 file written together by all ranks of ``domain``.

    Every method is called by every rank with the same arguments (attribute values, dataset
    shapes), in the same order: that is what the mpio driver requires, and in serial mode the
    calls are no-ops on the ranks that do not hold the file.
    """

    def __init__(self, path: Path, domain, mode: str, fsync: bool = False):
        self.path = Path(path)
        self.tmp = tmp_name(self.path)
        self.domain = domain
        self.mode = mode
        self.fsync = fsync
        self.h5: h5py.File | None = None
        # The first failure on this rank. A failing rank does not leave the collective protocol
        # (it joins the remaining writes with nothing to write); `commit` then raises the
        # error on every rank, so no rank is left waiting and no abort hook is needed.
        self.error: str | None = None
        if mode == "mpio":
            self.h5 = h5py.File(self.tmp, "w", driver="mpio", comm=domain.comm, libver=LIBVER)
        elif domain.rank == 0:
            self.h5 = h5py.File(self.tmp, "w", libver=LIBVER)

    @property
    def writes_here(self) -> bool:
        """Whether this rank holds the open file."""
        return self.h5 is not None

    def _serial_guard(self, what: str, action, *args):
        """Serial mode: run ``action`` on the rank that holds the file, recording a failure
        (and skipping everything after one) so the other ranks are not left waiting. mpio mode:
        these are collective calls that fail on every rank alike, so they raise as usual."""
        if self.mode != "serial":
            return action(*args)
        if self.error is not None:
            return None
        try:
            return action(*args)
        except Exception as exc:  # noqa: BLE001 - reported on every rank by commit
            self.fail(f"{self.tmp}: cannot write {what}: {_one_line(exc)}")
            return None

    def set_attrs(self, attrs: dict[str, Any], group: str = "/") -> None:
        if self.h5 is None:
            return

        def write() -> None:
            target = self.h5[group] if group in self.h5 else self.h5.require_group(group)
            for key, value in attrs.items():
                target.attrs[key] = attr_value(value)

        self._serial_guard(f"the attributes of {group}", write)

    def create(self, name: str, shape: tuple[int, ...], dtype) -> h5py.Dataset | None:
        """A contiguous dataset (no filters: parallel HDF5 writes filtered data only
        collectively and slower; particle data compresses poorly anyway)."""
        if self.h5 is None:
            return None
        return self._serial_guard(name, lambda: self.h5.create_dataset(
            name, shape=shape, dtype=np.dtype(dtype)))

    def write_small(self, name: str, array: np.ndarray) -> None:
        """A dataset rank 0 writes alone (metadata arrays); every rank calls this."""
        array = np.asarray(array)
        dset = self.create(name, array.shape, array.dtype)
        if dset is not None and self.domain.rank == 0 and array.size:
            self._serial_guard(name, dset.__setitem__, Ellipsis, array)

    def fail(self, message: str) -> None:
        """Record a failure on this rank (the first one is kept); `commit` reports it."""
        if self.error is None:
            self.error = message

    def write_rows(self, dset: h5py.Dataset, first: int, data: np.ndarray) -> None:
        """Serial mode (the rank that holds the file): ``data`` into rows ``first...``; a
        failure is recorded, and later pieces are skipped, so the other ranks still hand over
        theirs and the protocol ends normally."""
        if self.error is not None or dset is None:
            return
        try:
            dset[first:first + len(data)] = data
        except Exception as exc:  # noqa: BLE001 - reported on every rank by commit
            self.fail(f"{self.tmp}: cannot write {dset.name}: {_one_line(exc)}")

    def write_runs(self, dset: h5py.Dataset, starts: np.ndarray, counts: np.ndarray,
                   data: np.ndarray) -> None:
        """mpio: this rank's ``data`` goes to the row runs ``[start, start+count)`` (in order)
        by collective writes; a rank with fewer runs joins the remaining writes with an empty
        selection.

        At most `RUNS_PER_WRITE` runs per write: HDF5 1.10 builds a union of hyperslabs in time
        quadratic in their number (20000 runs took 24 s to select, 256 take 1.2 ms), while the
        write itself is fast, so many small unions beat one big one."""
        n_calls = self.domain.max(-(-len(starts) // RUNS_PER_WRITE))
        ends = np.cumsum(counts)
        try:
            data = np.ascontiguousarray(data, dtype=dset.dtype)
        except Exception as exc:  # noqa: BLE001 - this rank joins with empty selections
            self.fail(f"{self.tmp}: cannot write {dset.name}: {_one_line(exc)}")
        for call in range(n_calls):
            lo, hi = call * RUNS_PER_WRITE, min((call + 1) * RUNS_PER_WRITE, len(starts))
            first = int(ends[lo - 1]) if 0 < lo <= len(starts) else 0
            last = int(ends[hi - 1]) if hi > lo else first
            selection = None
            if self.error is None:
                try:
                    selection = self._selection(dset, starts[lo:hi], counts[lo:hi],
                                                data[first:last])
                except Exception as exc:  # noqa: BLE001 - reported on every rank by commit
                    self.fail(f"{self.tmp}: cannot write {dset.name}: {_one_line(exc)}")
            # A failed rank still takes part, with nothing to write, so the collective ends.
            selection = selection or self._nothing(dset)
            try:
                self._write(dset, *selection)
            except Exception as exc:  # noqa: BLE001 - reported on every rank by commit
                self.fail(f"{self.tmp}: cannot write {dset.name}: {_one_line(exc)}")

    @staticmethod
    def _selection(dset: h5py.Dataset, starts, counts, data: np.ndarray):
        """(memory space, file space, data) of one collective write: local work only."""
        from h5py import h5s

        trailing = dset.shape[1:]
        fspace = dset.id.get_space()
        fspace.select_none()
        for start, count in zip(np.asarray(starts).tolist(), np.asarray(counts).tolist()):
            fspace.select_hyperslab((start,) + (0,) * len(trailing), (count,) + trailing,
                                    op=h5s.SELECT_OR)
        if len(data) == 0:
            return SharedFile._nothing(dset)
        return h5s.create_simple(data.shape), fspace, data

    @staticmethod
    def _nothing(dset: h5py.Dataset):
        """The empty selection a rank joins a collective write with."""
        from h5py import h5s

        fspace = dset.id.get_space()
        fspace.select_none()
        data = np.zeros((1,) + dset.shape[1:], dtype=dset.dtype)
        mspace = h5s.create_simple(data.shape)
        mspace.select_none()
        return mspace, fspace, data

    @staticmethod
    def _write(dset: h5py.Dataset, mspace, fspace, data: np.ndarray) -> None:
        """The collective write itself (every rank calls it)."""
        from h5py import h5fd, h5p

        dxpl = h5p.create(h5p.DATASET_XFER)
        dxpl.set_dxpl_mpio(h5fd.MPIO_COLLECTIVE)
        dset.id.write(mspace, fspace, data, dxpl=dxpl)

    def commit(self) -> Path:
        """Close, (fsync,) rename ``NAME.tmp`` to ``NAME`` on rank 0; every rank returns once
        the final file exists. A failure on any rank (recorded by `fail` or met here) is raised
        as the same `OSError` on every rank, and the temporary file is removed."""
        error = self.error
        if self.h5 is not None:
            try:
                self.h5.close()  # collective in mpio mode
            except Exception as exc:  # noqa: BLE001 - reported on every rank below
                error = error or f"{self.tmp}: cannot finish the file: {_one_line(exc)}"
            self.h5 = None
        # Whether every rank wrote its part, decided together before the rename.
        errors = [e for e in self.domain.allgather(error) if e]
        if self.domain.rank == 0 and not errors:
            try:
                replace_atomically(self.tmp, self.path, self.fsync)
            except OSError as exc:
                error = f"{self.path}: cannot rename {self.tmp.name} into place: {exc}"
            errors = [error] if error else []
        errors = self.domain.bcast(errors)
        if errors:
            if self.domain.rank == 0:
                self.tmp.unlink(missing_ok=True)
            raise OSError(errors[0])
        return self.path

    def abandon(self) -> None:
        """Close and remove the temporary file after a failure on this rank."""
        try:
            if self.h5 is not None:
                self.h5.close()
        except Exception:  # noqa: BLE001
            pass
        if self.domain.rank == 0:
            self.tmp.unlink(missing_ok=True)


# -- serial mode: rows travel to rank 0 ------------------------------------------------------
def send_rows_in_turn(domain, rows: dict[str, np.ndarray], chunk_bytes: int,
                      sink: Callable[[int, dict[str, np.ndarray]], None]) -> int:
    """Rank-ordered layout: rank r's rows follow rank r-1's. Rank 0 calls
    ``sink(first_row, piece)`` for its own rows, then for every piece the other ranks send it in
    turn (point to point, at most ``chunk_bytes`` each). Returns the global row count."""
    n = len(next(iter(rows.values()))) if rows else 0
    counts = domain.allgather(n)
    row_bytes = sum(a.itemsize * int(np.prod(a.shape[1:])) for a in rows.values())
    step = rows_per_piece(row_bytes, chunk_bytes)
    if domain.rank == 0:
        offset = 0
        for source, count in enumerate(counts):
            for start in range(0, count, step):
                piece = ({k: a[start:start + step] for k, a in rows.items()} if source == 0
                         else domain.recv(source, tag=7))
                sink(offset + start, piece)
            offset += count
    else:
        for start in range(0, n, step):
            domain.send({k: a[start:start + step] for k, a in rows.items()}, 0, tag=7)
    return int(sum(counts))


def gather_by_id(domain, ids: np.ndarray, rows: dict[str, np.ndarray], chunk_bytes: int,
                 sink: Callable[[int, dict[str, np.ndarray] | None], None]) -> None:
    """Id-ordered layout: rank 0 calls ``sink(first_row, piece)`` with consecutive pieces of
    the rows of all ranks sorted by id; ``ids`` and ``rows`` are this rank's, sorted by id.
    The other ranks call ``sink(first_row, None)`` in the same rounds (for collective writes).

    Rounds: all ranks agree on an id bound ``U``; each hands rank 0 its rows with ids below
    ``U`` not yet sent; rank 0 merges them by id. ``U`` is the larger of (lowest pending id +
    B) and the smallest over ranks of "the id B/size rows further on", B rows = chunk_bytes/2,
    so a piece holds at most ~chunk_bytes whatever the id gaps, and dense ids (0..N-1) take
    N/B rounds.
    """
    row_bytes = sum(a.itemsize * int(np.prod(a.shape[1:])) for a in rows.values())
    block = rows_per_piece(row_bytes, chunk_bytes // 2)
    stride = max(1, block // domain.size)
    cursor, written, n = 0, 0, len(ids)
    while True:
        lowest = int(ids[cursor]) if cursor < n else None
        ahead = int(ids[cursor + stride]) if cursor + stride < n else None
        proposals = domain.allgather((lowest, ahead))
        lows = [lo for lo, _ in proposals if lo is not None]
        if not lows:
            return
        aheads = [a for _, a in proposals if a is not None]
        bound = min(lows) + block
        if aheads:
            bound = max(bound, min(aheads))
        stop = int(np.searchsorted(ids, bound, side="left"))
        piece = {k: a[cursor:stop] for k, a in rows.items()}
        piece["__id__"] = ids[cursor:stop]
        cursor = stop
        pieces = domain.gather(piece)
        if domain.rank == 0:
            merged_ids = np.concatenate([p["__id__"] for p in pieces])
            order = np.argsort(merged_ids, kind="stable")
            merged = {k: np.concatenate([p[k] for p in pieces])[order] for k in rows}
            sink(written, merged)
            written += len(order)
        else:
            sink(0, None)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__

"""Point-to-point building blocks: particle rows packed as bytes, grid regions packed as
float64, and the non-blocking send/receive of one buffer per neighbour.

Packing is numpy slicing only (no Python loop over particles or nodes): a particle is one row
of a ``(m, row_bytes)`` uint8 array holding every field side by side, so the particles for one
destination are one contiguous block of rows and one message.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

# Message tags, one per kind of exchange, so two exchanges can never match each other's data.
TAG_MIGRATE, TAG_SUM, TAG_FILL, TAG_HALO_COUNT, TAG_HALO = 101, 102, 103, 104, 105


@dataclass(frozen=True)
class Column:
    """Where one field sits in a packed particle row."""

    name: str
    dtype: np.dtype
    trailing: tuple[int, ...]
    offset: int
    nbytes: int


def row_layout(arrays: dict[str, np.ndarray]) -> list[Column]:
    """Layout of a packed row for these fields. Names are sorted, so ranks that declared the
    same fields in a different order still agree on the bytes."""
    columns, offset = [], 0
    for name in sorted(arrays):
        a = arrays[name]
        nbytes = a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64))
        columns.append(Column(name, a.dtype, tuple(a.shape[1:]), offset, nbytes))
        offset += nbytes
    return columns


def pack_rows(arrays: dict[str, np.ndarray], index: np.ndarray, layout: list[Column]) -> np.ndarray:
    """Rows ``index`` of every field, side by side: (len(index), row_bytes) uint8."""
    m = len(index)
    buf = np.empty((m, row_bytes(layout)), dtype=np.uint8)
    for c in layout:
        rows = np.ascontiguousarray(arrays[c.name][index])
        buf[:, c.offset:c.offset + c.nbytes] = rows.view(np.uint8).reshape(m, c.nbytes)
    return buf


def unpack_rows(buf: np.ndarray, layout: list[Column]) -> dict[str, np.ndarray]:
    """Inverse of `pack_rows`: a dict of arrays (m, *trailing) with the original dtypes."""
    m = len(buf)
    out = {}
    for c in layout:
        raw = np.ascontiguousarray(buf[:, c.offset:c.offset + c.nbytes])
        out[c.name] = raw.view(c.dtype).reshape((m,) + c.trailing)
    return out


def row_bytes(layout: list[Column]) -> int:
    return layout[-1].offset + layout[-1].nbytes if layout else 0


def exchange_rows(comm: MPI.Comm, send: np.ndarray, send_counts: np.ndarray,
                  recv_counts: np.ndarray, tag: int) -> np.ndarray:
    """Send rows ``send`` (grouped by destination, ``send_counts[r]`` rows for rank ``r``) and
    receive ``recv_counts[r]`` rows from each rank; messages only where a count is nonzero.
    Returns the received rows grouped by source rank."""
    width = send.shape[1] if send.ndim == 2 else 0
    recv = np.empty((int(recv_counts.sum()), width), dtype=np.uint8)
    if width == 0:
        return recv
    requests = []
    start = 0
    for source, count in enumerate(recv_counts):
        if count:
            requests.append(comm.Irecv(recv[start:start + count], source=source, tag=tag))
            start += count
    start = 0
    for dest, count in enumerate(send_counts):
        if count:
            requests.append(comm.Isend(send[start:start + count], dest=dest, tag=tag))
            start += count
    MPI.Request.Waitall(requests)
    return recv


def region_slices(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, shape) -> tuple:
    """Slices of the global node box ``[lo, hi)`` in a block allocated at ``origin``."""
    if np.any(lo < origin) or np.any(hi > origin + np.asarray(shape)):
        raise RuntimeError(
            f"grid block [{origin.tolist()}, {(origin + np.asarray(shape)).tolist()}) does not hold "
            f"the exchanged nodes [{lo.tolist()}, {hi.tolist()}): fit the block to "
            "domain.grid_box(particles, order) before the halo exchange")
    return tuple(slice(int(l - o), int(h - o)) for l, h, o in zip(lo, hi, origin))


def pack_region(fields: list[np.ndarray], slices: tuple, buf: np.ndarray) -> None:
    """Copy the region ``slices`` of each field (scalar or vector) into ``buf``, one after the
    other."""
    start = 0
    for f in fields:
        part = f[slices]
        buf[start:start + part.size].reshape(part.shape)[...] = part
        start += part.size


def region_size(fields: list[np.ndarray], slices: tuple) -> int:
    n_nodes = int(np.prod([s.stop - s.start for s in slices]))
    return sum(n_nodes * int(np.prod(f.shape[len(slices):], dtype=np.int64)) for f in fields)


def unpack_region(fields: list[np.ndarray], slices: tuple, buf: np.ndarray, add: bool) -> None:
    """Add (``add``) or copy ``buf`` into the region ``slices`` of each field."""
    start = 0
    for f in fields:
        part = f[slices]
        values = buf[start:start + part.size].reshape(part.shape)
        if add:
            part += values
        else:
            part[...] = values
        start += part.size

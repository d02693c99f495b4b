"""Point-to-point building blocks: particle rows packed as bytes, the slices of a grid
region, and the non-blocking send/receive of one buffer per neighbour.

Packing is numpy slicing only (no Python loop over particles): a particle is one packed record
holding every field side by side (a numpy structured dtype built from the fields), so the
particles for one destination are one contiguous run of records and one message. Grid regions
travel as float64, packed by kernels over their node lists (`Domain._exchange_regions`).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

# Message tags, one per kind of exchange, so two exchanges can never match each other's data.
TAG_MIGRATE, TAG_SUM, TAG_FILL, TAG_HALO_COUNT, TAG_HALO = 101, 102, 103, 104, 105


def row_dtype(arrays: dict[str, np.ndarray]) -> np.dtype:
    """Packed record type of one particle: every field of ``arrays`` (any dtype, any trailing
    shape) side by side. Names are sorted, so ranks that declared the same fields in a
    different order still agree on the bytes."""
    return np.dtype([(name, arrays[name].dtype, arrays[name].shape[1:])
                     for name in sorted(arrays)])


def pack_rows(arrays: dict[str, np.ndarray], index: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Records (len(index),) of ``dtype`` holding rows ``index`` of every field."""
    rows = np.empty(len(index), dtype=dtype)
    for name in dtype.names:
        rows[name] = arrays[name][index]
    return rows


def unpack_rows(rows: np.ndarray) -> dict[str, np.ndarray]:
    """The fields of received records, as (strided) views: (m, *trailing) each."""
    return {name: rows[name] for name in rows.dtype.names}


def exchange_rows(comm, send: np.ndarray, dests: np.ndarray, send_counts: np.ndarray,
                  sources: np.ndarray, recv_counts: np.ndarray, tag: int) -> np.ndarray:
    """Send records ``send`` (grouped by destination: ``send_counts[i]`` for rank
    ``dests[i]``) and receive ``recv_counts[i]`` records from rank ``sources[i]``; messages
    only where a count is nonzero. Returns the received records in the order of ``sources``.
    Records travel as bytes; the ones a rank sends itself (periodic images) are copied
    (its entries in both lists must then agree)."""
    recv = np.empty(int(np.sum(recv_counts)), dtype=send.dtype)
    if send.dtype.itemsize == 0:
        return recv
    me = comm.Get_rank()
    send_start = np.concatenate([[0], np.cumsum(send_counts)]).astype(np.int64)
    recv_start = np.concatenate([[0], np.cumsum(recv_counts)]).astype(np.int64)
    own = {int(d): i for i, d in enumerate(dests) if d == me}
    requests = []
    for i in np.flatnonzero(recv_counts):
        start, stop = int(recv_start[i]), int(recv_start[i + 1])
        if sources[i] == me:
            j = own[me]
            recv[start:stop] = send[send_start[j]:send_start[j + 1]]
            continue
        requests.append(comm.Irecv(recv[start:stop].view(np.uint8), source=int(sources[i]),
                                   tag=tag))
    for i in np.flatnonzero(send_counts):
        if dests[i] == me:
            continue
        start, stop = int(send_start[i]), int(send_start[i + 1])
        requests.append(comm.Isend(send[start:stop].view(np.uint8), dest=int(dests[i]),
                                   tag=tag))
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

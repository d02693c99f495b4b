"""Collective verbs on scalars and small objects: the only MPI that code outside `parallel/`
reaches, through `Domain` (which inherits these). A 1-rank run goes through the same calls.

Traffic counting (`Communicator.count_traffic`): every MPI call this package makes goes
through ``self.mpi``, which is the mpi4py communicator itself (nothing to pay when counting is
off) or a `CountingComm` around it that tallies point-to-point messages and bytes sent,
neighbour-collective messages (one per neighbour) and global collectives with their payload.
``self.comm`` stays the plain communicator for h5py's mpio driver.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from mpi4py import MPI


@dataclass
class TrafficCounts:
    """What this rank sent since the last `reset`: point-to-point messages and bytes
    (neighbour collectives count one message per neighbour), global collectives and the
    bytes this rank contributed to them, and the largest single collective payload."""

    messages: int = 0
    bytes: int = 0
    collectives: int = 0
    collective_bytes: int = 0
    largest_collective: int = 0
    by_kind: dict = field(default_factory=dict)  # collective name -> count

    def reset(self) -> None:
        self.messages = self.bytes = self.collectives = 0
        self.collective_bytes = self.largest_collective = 0
        self.by_kind = {}

    def message(self, nbytes: int, count: int = 1) -> None:
        self.messages += count
        self.bytes += int(nbytes)

    def collective(self, kind: str, nbytes: int) -> None:
        self.collectives += 1
        self.collective_bytes += int(nbytes)
        self.largest_collective = max(self.largest_collective, int(nbytes))
        self.by_kind[kind] = self.by_kind.get(kind, 0) + 1

    def as_dict(self) -> dict:
        return {"messages": self.messages, "bytes": self.bytes,
                "collectives": self.collectives, "collective_bytes": self.collective_bytes,
                "largest_collective": self.largest_collective, "by_kind": dict(self.by_kind)}


def _nbytes(buf) -> int:
    """Bytes of an mpi4py buffer argument: an array, or [array, datatype] and the like."""
    if isinstance(buf, (list, tuple)):
        buf = buf[0]
    if buf is None or buf is MPI.IN_PLACE:
        return 0
    return int(np.asarray(buf).nbytes) if not isinstance(buf, (bytes, bytearray)) \
        else len(buf)


def _pickled(obj) -> int:
    return len(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL))


class CountingComm:
    """An mpi4py communicator that counts what passes through it (see module docstring).
    Only the calls `hpcmpm.parallel` makes are wrapped; anything else is refused, so a new
    call cannot slip past the counts."""

    _PLAIN = ("Get_rank", "Get_size", "Abort", "Free", "rank", "size", "Get_dist_neighbors",
              "Get_dist_neighbors_count")

    def __init__(self, comm, counts: TrafficCounts):
        self._comm = comm
        self.counts = counts

    def __getattr__(self, name):
        if name in self._PLAIN:
            return getattr(self._comm, name)
        raise AttributeError(f"CountingComm does not wrap {name!r}: add it with its count")

    # point to point
    def Isend(self, buf, dest, tag=0):
        self.counts.message(_nbytes(buf))
        return self._comm.Isend(buf, dest=dest, tag=tag)

    def Irecv(self, buf, source, tag=0):
        return self._comm.Irecv(buf, source=source, tag=tag)

    def send(self, obj, dest, tag=0):
        self.counts.message(_pickled(obj))
        return self._comm.send(obj, dest=dest, tag=tag)

    def recv(self, source, tag=0):
        return self._comm.recv(source=source, tag=tag)

    # neighbour collectives: one message to each neighbour
    def Neighbor_allgather(self, sendbuf, recvbuf):
        degree = self._comm.Get_dist_neighbors_count()[1]
        self.counts.message(_nbytes(sendbuf) * degree, degree)
        return self._comm.Neighbor_allgather(sendbuf, recvbuf)

    def Neighbor_alltoall(self, sendbuf, recvbuf):
        degree = self._comm.Get_dist_neighbors_count()[1]
        self.counts.message(_nbytes(sendbuf), degree)
        return self._comm.Neighbor_alltoall(sendbuf, recvbuf)

    # global collectives
    def _collective(self, kind: str, nbytes: int):
        self.counts.collective(kind, nbytes)
        return getattr(self._comm, kind)

    def Allreduce(self, sendbuf, recvbuf, op=MPI.SUM):
        return self._collective("Allreduce", _nbytes(sendbuf))(sendbuf, recvbuf, op=op)

    def Allgather(self, sendbuf, recvbuf):
        return self._collective("Allgather", _nbytes(sendbuf))(sendbuf, recvbuf)

    def Alltoall(self, sendbuf, recvbuf):
        return self._collective("Alltoall", _nbytes(sendbuf))(sendbuf, recvbuf)

    def Barrier(self):
        return self._collective("Barrier", 0)()

    def allreduce(self, obj, op=MPI.SUM):
        return self._collective("allreduce", _pickled(obj))(obj, op=op)

    def allgather(self, obj):
        return self._collective("allgather", _pickled(obj))(obj)

    def gather(self, obj, root=0):
        return self._collective("gather", _pickled(obj))(obj, root=root)

    def bcast(self, obj, root=0):
        return self._collective("bcast", _pickled(obj))(obj, root=root)

    def exscan(self, obj, op=MPI.SUM):
        return self._collective("exscan", _pickled(obj))(obj, op=op)

    def Split_type(self, split_type, key=0):
        return self._collective("Split_type", 8)(split_type, key=key)

    def Create_dist_graph_adjacent(self, sources, destinations, reorder=False):
        graph = self._collective("Create_dist_graph_adjacent", 8 * len(destinations))(
            sources, destinations, reorder=reorder)
        return CountingComm(graph, self.counts)


class Communicator:
    """Thin verbs over an mpi4py communicator (``COMM_WORLD`` by default)."""

    def __init__(self, comm: MPI.Comm | None = None):
        self.comm = MPI.COMM_WORLD if comm is None else comm
        self.mpi = self.comm  # what this package calls: the comm, or a CountingComm of it
        self.traffic: TrafficCounts | None = None
        self.rank = self.comm.Get_rank()
        self.size = self.comm.Get_size()

    def count_traffic(self) -> TrafficCounts:
        """Start counting this rank's MPI traffic (`TrafficCounts`, reset it to measure a
        stretch); a communicator created afterwards (the neighbour graph) is counted too."""
        if self.traffic is None:
            self.traffic = TrafficCounts()
            self.mpi = CountingComm(self.comm, self.traffic)
            self._traffic_started()
        return self.traffic

    def _traffic_started(self) -> None:
        """Hook for subclasses that hold further communicators."""

    # Decide together: every branch on these values is taken by all ranks alike.
    def min(self, x: float) -> float:
        return self.mpi.allreduce(x, op=MPI.MIN)

    def max(self, x: float) -> float:
        return self.mpi.allreduce(x, op=MPI.MAX)

    def sum(self, x):
        """Sum of a scalar or a numpy array over ranks (arrays: small ones only)."""
        if isinstance(x, np.ndarray):
            out = np.empty_like(x)
            self.mpi.Allreduce(np.ascontiguousarray(x), out, op=MPI.SUM)
            return out
        return self.mpi.allreduce(x, op=MPI.SUM)

    def any(self, flag: bool) -> bool:
        return bool(self.mpi.allreduce(bool(flag), op=MPI.LOR))

    def exscan(self, n: int) -> int:
        """Exclusive prefix sum of a 64-bit count (0 on rank 0): a rank's offset in a file."""
        out = self.mpi.exscan(int(n), op=MPI.SUM)
        return 0 if out is None else int(out)

    def allgather(self, obj: Any) -> list:
        return self.mpi.allgather(obj)

    def gather(self, obj: Any, root: int = 0) -> list | None:
        return self.mpi.gather(obj, root=root)

    def bcast(self, obj: Any, root: int = 0) -> Any:
        return self.mpi.bcast(obj, root=root)

    def send(self, obj: Any, dest: int, tag: int = 0) -> None:
        self.mpi.send(obj, dest=dest, tag=tag)

    def recv(self, source: int, tag: int = 0) -> Any:
        return self.mpi.recv(source=source, tag=tag)

    def ranks_on_node(self) -> int:
        """How many ranks of this communicator share this rank's node (its memory)."""
        if getattr(self, "_ranks_on_node", None) is None:
            node = self.mpi.Split_type(MPI.COMM_TYPE_SHARED)
            self._ranks_on_node = node.Get_size()
            node.Free()
        return self._ranks_on_node

    def barrier(self) -> None:
        self.mpi.Barrier()

    def abort(self, code: int = 1) -> None:
        self.comm.Abort(code)

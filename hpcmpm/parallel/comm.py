"""Collective verbs on scalars and small objects: the only MPI that code outside `parallel/`
reaches, through `Domain` (which inherits these). A 1-rank run goes through the same calls."""

from __future__ import annotations

from typing import Any

import numpy as np
from mpi4py import MPI


class Communicator:
    """Thin verbs over an mpi4py communicator (``COMM_WORLD`` by default)."""

    def __init__(self, comm: MPI.Comm | None = None):
        self.comm = MPI.COMM_WORLD if comm is None else comm
        self.rank = self.comm.Get_rank()
        self.size = self.comm.Get_size()

    # Decide together: every branch on these values is taken by all ranks alike.
    def min(self, x: float) -> float:
        return self.comm.allreduce(x, op=MPI.MIN)

    def max(self, x: float) -> float:
        return self.comm.allreduce(x, op=MPI.MAX)

    def sum(self, x):
        """Sum of a scalar or a numpy array over ranks (arrays: small ones only)."""
        if isinstance(x, np.ndarray):
            out = np.empty_like(x)
            self.comm.Allreduce(np.ascontiguousarray(x), out, op=MPI.SUM)
            return out
        return self.comm.allreduce(x, op=MPI.SUM)

    def any(self, flag: bool) -> bool:
        return bool(self.comm.allreduce(bool(flag), op=MPI.LOR))

    def exscan(self, n: int) -> int:
        """Exclusive prefix sum of a 64-bit count (0 on rank 0): a rank's offset in a file."""
        out = self.comm.exscan(int(n), op=MPI.SUM)
        return 0 if out is None else int(out)

    def allgather(self, obj: Any) -> list:
        return self.comm.allgather(obj)

    def gather(self, obj: Any, root: int = 0) -> list | None:
        return self.comm.gather(obj, root=root)

    def bcast(self, obj: Any, root: int = 0) -> Any:
        return self.comm.bcast(obj, root=root)

    def send(self, obj: Any, dest: int, tag: int = 0) -> None:
        self.comm.send(obj, dest=dest, tag=tag)

    def recv(self, source: int, tag: int = 0) -> Any:
        return self.comm.recv(source=source, tag=tag)

    def barrier(self) -> None:
        self.comm.Barrier()

    def abort(self, code: int = 1) -> None:
        self.comm.Abort(code)

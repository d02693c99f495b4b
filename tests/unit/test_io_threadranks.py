"""In-process stand-in for N MPI ranks (threads), so the I/O tests exercise multi-rank layouts
in the plain test run; tests/mpi/test_io_modes.py does the same under a real mpiexec."""

from __future__ import annotations

import pickle
import queue
import threading

import numpy as np

TIMEOUT = 60.0  # a deadlock fails the test instead of hanging it


class _Hub:
    def __init__(self, size: int):
        self.size = size
        self.barrier = threading.Barrier(size, timeout=TIMEOUT)
        self.slots: list = [None] * size
        self.lock = threading.Lock()
        self.queues: dict = {}

    def queue(self, key) -> queue.Queue:
        with self.lock:
            return self.queues.setdefault(key, queue.Queue())


class ThreadComm:
    """The `Communicator` verbs over threads; messages are pickled like mpi4py's."""

    def __init__(self, hub: _Hub, rank: int):
        self.hub, self.rank, self.size = hub, rank, hub.size
        self.comm = None

    def allgather(self, obj):
        self.hub.slots[self.rank] = pickle.dumps(obj)
        self.hub.barrier.wait()
        out = [pickle.loads(s) for s in self.hub.slots]
        self.hub.barrier.wait()
        return out

    def gather(self, obj, root: int = 0):
        out = self.allgather(obj)
        return out if self.rank == root else None

    def bcast(self, obj, root: int = 0):
        return self.allgather(obj)[root]

    def min(self, x):
        return min(self.allgather(x))

    def max(self, x):
        return max(self.allgather(x))

    def sum(self, x):
        return sum(self.allgather(x))

    def any(self, flag):
        return any(self.allgather(bool(flag)))

    def exscan(self, n):
        return int(sum(self.allgather(int(n))[: self.rank]))

    def send(self, obj, dest: int, tag: int = 0):
        self.hub.queue((self.rank, dest, tag)).put(pickle.dumps(obj))

    def recv(self, source: int, tag: int = 0):
        return pickle.loads(self.hub.queue((source, self.rank, tag)).get(timeout=TIMEOUT))

    def barrier(self):
        self.hub.barrier.wait()


def run_ranks(size: int, fn):
    """Call ``fn(comm)`` on ``size`` thread ranks; returns the results in rank order and
    re-raises the first exception."""
    hub = _Hub(size)
    results: list = [None] * size
    errors: list = [None] * size

    def body(rank):
        try:
            results[rank] = fn(ThreadComm(hub, rank))
        except BaseException as exc:  # noqa: BLE001
            errors[rank] = exc
            hub.barrier.abort()

    threads = [threading.Thread(target=body, args=(r,)) for r in range(size)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(TIMEOUT * 2)
    real = [e for e in errors if e is not None and not isinstance(e, threading.BrokenBarrierError)]
    if real or any(errors):
        raise (real or [e for e in errors if e])[0]
    return results


def test_thread_ranks_verbs():
    out = run_ranks(3, lambda c: (c.exscan(c.rank + 1), c.sum(np.ones(2))[0], c.bcast(c.rank, 2)))
    assert out == [(0, 3.0, 2), (1, 3.0, 2), (3, 3.0, 2)]

"""The Domain: which particles and grid nodes a rank holds, and every exchange between ranks.

Verbs only (STYLE.md "One MPI seam"): the time step calls ``grid_box``, ``sum_ghosts_to_owners``,
``fill_ghosts``, ``migrate``; the scalar collectives come from `Communicator`. A 1-rank run goes
through the same object; its exchanges have no neighbours and send nothing.

Ownership (ARCHITECTURE.md): rank ``r`` owns the cells ``boxes[r] = [lo, hi)`` and the nodes with
the same indices. A particle in cell ``c`` touches nodes ``c-1 .. c+2`` for both B-spline kernels,
so a rank's support box is ``[min cell - 1, max cell + 3)``.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

from ..kernels.grid import gather_nodes, scatter_nodes
from .comm import Communicator, CountingComm
from .decomposition import (BIG, cell_bounds, intersect, is_empty, leavers,
                            neighbour_ranks, owner_ranks, particle_cells, points_in_boxes,
                            recursive_bisection, wrap_periodic)
from .exchange import (TAG_FILL, TAG_HALO, TAG_HALO_COUNT, TAG_MIGRATE, TAG_SUM, exchange_rows,
                       pack_rows, region_slices, row_dtype, unpack_rows)

# The particle field of reference positions, which moves with x across periodic faces.
FOLLOWS_WRAPS = "x0"
# Kernel support around a particle's cell, in nodes: 1 below, 2 above (quadratic and cubic).
GHOST_BELOW, GHOST_ABOVE = 1, 2
# Cells around a rank's box within which its neighbours' boxes lie. A rank's particles stay in
# its box (every step ends with `migrate`), so its support is inside [lo - 1, hi + 2); 3 also
# covers a particle that crossed a face by less than 2 cells in one step (CFL <= 2).
NEIGHBOUR_REACH = 3
# Seconds a rank that dies of an uncaught exception waits, after printing it, before
# MPI_Abort (`install_abort_hook`).
ABORT_GRACE_S = 0.5


def image_steps(n_cells: int) -> tuple[int, ...]:
    """The periodic images, in periods, along an axis of ``n_cells`` cells: 0, -1, +1, ...,
    -k, +k with k = ceil(NEIGHBOUR_REACH / n_cells) (at least 1), the images whose cells
    lie within NEIGHBOUR_REACH of the domain [0, n)."""
    k = max(1, -(-NEIGHBOUR_REACH // int(n_cells)))
    return (0, *[s for j in range(1, k + 1) for s in (-j, j)])


def _max_then_sum(inbuf, inoutbuf, datatype) -> None:
    """MPI reduction of float64 vectors ``[k, max_1 .. max_k, sum_1 ..]``: elementwise max of
    the first k + 1 entries, sum of the rest. Counts are integers below 2**53: exact."""
    a = np.frombuffer(inbuf, dtype=np.float64)
    b = np.frombuffer(inoutbuf, dtype=np.float64)
    k = int(a[0]) + 1
    np.maximum(a[:k], b[:k], out=b[:k])
    b[k:] += a[k:]


_MAX_THEN_SUM = None


def max_then_sum_op():
    global _MAX_THEN_SUM
    if _MAX_THEN_SUM is None:
        _MAX_THEN_SUM = MPI.Op.Create(_max_then_sum, commute=True)
    return _MAX_THEN_SUM


@dataclass
class GridPlan:
    """Who exchanges which node boxes this step; recomputed only when the support boxes of
    this rank or of its neighbours, or the decomposition, change.

    ``to_owners[k] = (r, [(lo, hi), ...])``: boxes of my block (global node indices, as my
    block holds them) that are nodes of rank ``r``'s owned box, directly or through a periodic
    image (I send my partial sums there; ``fill_ghosts`` receives the owner's values there).
    ``from_touchers[k] = (r, [(lo, hi), ...])``: my owned nodes that rank ``r``'s particles
    touch, in the same order as ``r`` lists the matching boxes. Both lists are in rank order
    and each rank's boxes in the order of `Domain.shifts`; ``r`` may be this rank itself when
    a periodic axis wraps its support onto its own owned nodes (copied, not sent).
    """

    key: bytes
    block_lo: np.ndarray
    block_hi: np.ndarray
    to_owners: list = field(default_factory=list)
    from_touchers: list = field(default_factory=list)


def make_domain(scene, comm: Communicator | None = None) -> "Domain":
    """The `Domain` of a scene (its box, dx and periodic axes) over ``comm`` (COMM_WORLD by
    default)."""
    return Domain(scene.dim, scene.dx, scene.domain_lo, scene.domain_hi,
                  comm=None if comm is None else comm.comm,
                  periodic=getattr(scene, "periodic", ()))


class Domain(Communicator):
    """Decomposition of the cell index space over the ranks, and the exchanges it implies.

    Parameters
    ----------
    dim : 2 or 3.
    dx : grid spacing.
    domain_lo, domain_hi : corners of the domain box (dim,).
    comm : an mpi4py communicator or a `Communicator` (``COMM_WORLD`` by default).
    periodic : indices of the periodic axes (``Scene.periodic``). Along such an axis of
        ``n`` cells, node ``i`` is node ``i mod n``, the rank boxes tile ``[0, n)`` and
        `migrate` wraps positions into the domain.
    """

    def __init__(self, dim: int, dx: float, domain_lo, domain_hi, comm=None, periodic=()):
        super().__init__(comm.comm if isinstance(comm, Communicator) else comm)
        self.dim = int(dim)
        self.dx = float(dx)
        self.inv_dx = 1.0 / self.dx
        self.domain_lo = np.asarray(domain_lo, dtype=np.float64).reshape(self.dim)
        self.domain_hi = np.asarray(domain_hi, dtype=np.float64).reshape(self.dim)
        self.n_cells = np.round((self.domain_hi - self.domain_lo) / self.dx).astype(np.int64)
        self.periodic = np.zeros(self.dim, dtype=bool)
        self.periodic[list(periodic)] = True
        self._any_periodic = bool(self.periodic.any())   # tested every step (`wrap`)
        # Period in cells per axis, 0 where the axis is not periodic (the wrap kernel's input).
        self.period = np.where(self.periodic, self.n_cells, 0).astype(np.int64)
        # Image offsets in cells: every combination of 0, -1, +1, ..., -k, +k periods over the
        # periodic axes, zero first. A rank's supports and neighbours lie within
        # NEIGHBOUR_REACH cells of its box, so an image k periods away matters while
        # (k - 1) n < NEIGHBOUR_REACH: k = 1 from 3 cells up, more on a narrower axis (on one
        # cell a wrapped particle's support, nodes -1 .. 2, is node 0 four times; with one
        # image each way node 2 was lost, and a 1-cell channel drove a cross-flow).
        steps = [image_steps(n) if p else (0,) for p, n in zip(self.periodic, self.n_cells)]
        self.shifts = np.array(list(itertools.product(*steps)), dtype=np.int64) * self.period
        self._plan: GridPlan | None = None
        self._boxes_plan: GridPlan | None = None
        self._boxes_cache: dict = {}
        self._dots_range = None
        self._graph = None  # the neighbour graph communicator, built on first use
        self.neighbours = np.empty(0, dtype=np.int64)
        # Particles `migrate` kept because their owner is no neighbour: `agree` settles them.
        self.pending_far = 0
        self.moved_in_agree = 0
        self.arrived = 0  # particles received by migrations so far (a running count)
        # The run loop's stop request (a signal) and the agreed answer (`agree`).
        self.stop_requested = False
        self.stop_agreed = False
        # Until the first `decompose`, split the domain evenly (no particles: purely local).
        empty = np.empty((0, self.dim), dtype=np.int64)
        self.set_boxes(recursive_bisection(empty, self.size, self.n_cells,
                                           lambda a: a, lambda a: a, self.periodic))

    # -- decomposition ------------------------------------------------------------------------
    def decompose(self, particles, batch: int | None = None,
                  weights: np.ndarray | None = None) -> None:
        """Recursive coordinate bisection of the cells weighted by the particles on all ranks
        (by their integer ``weights`` (n,) when given, `Simulation.load_weights`), then move
        every particle to its owner (`migrate_all`, ``batch`` rows per round). Collective and
        deterministic."""
        self.wrap_particles(particles)
        cells = particle_cells(particles["x"], self.domain_lo, self.inv_dx)
        boxes = recursive_bisection(cells, self.size, self.n_cells,
                                    self._reduce_max, self._reduce_sum, self.periodic,
                                    weights)
        del cells
        self.set_boxes(boxes)
        self.migrate_all(particles, batch)

    def set_boxes(self, boxes: np.ndarray) -> None:
        """Adopt a decomposition (e.g. the one a checkpoint recorded): (size, 2, dim) cells.
        Collective: the neighbour graph is rebuilt on its next use."""
        boxes = np.array(boxes, dtype=np.int64)
        if boxes.shape != (self.size, 2, self.dim):
            raise ValueError(f"boxes must have shape {(self.size, 2, self.dim)} for {self.size} "
                             f"rank(s) in {self.dim}D, got {boxes.shape}")
        self.boxes = boxes
        self._plan = None
        if self._graph is not None:
            self._graph.Free()
        self._graph = None

    def _traffic_started(self) -> None:
        if self._graph is not None:
            self._graph = CountingComm(self._graph, self.traffic)

    @property
    def owned_lo(self) -> np.ndarray:
        return self.boxes[self.rank, 0]

    @property
    def owned_hi(self) -> np.ndarray:
        return self.boxes[self.rank, 1]

    def find_neighbours(self) -> np.ndarray:
        """Ranks whose box, or one of its periodic images, meets mine expanded by
        `NEIGHBOUR_REACH` cells. They hold every node my particles touch and every particle
        that touches my nodes."""
        return neighbour_ranks(self.boxes, self.rank, self.shifts, NEIGHBOUR_REACH)

    def _neighbour_graph(self):
        """The distributed-graph communicator of my neighbours (MPI-3 neighbour collectives),
        built collectively the first time a step needs it after the boxes changed."""
        if self._graph is None:
            self.neighbours = self.find_neighbours()
            others = np.setdiff1d(np.arange(self.size), self.neighbours)
            # Owner lookup tries my box, then my neighbours', then everybody's.
            self._search = np.concatenate([[self.rank], self.neighbours,
                                           others[others != self.rank]]).astype(np.int64)
            nbrs = [int(r) for r in self.neighbours]
            self._graph = self.mpi.Create_dist_graph_adjacent(nbrs, nbrs, reorder=False)
        return self._graph

    def period_lengths(self) -> np.ndarray:
        """The period of each axis as a length, 0 where the axis is not periodic."""
        return self.period * self.dx

    def wrap(self, x: np.ndarray, follow: np.ndarray | None = None) -> int:
        """Wrap positions x (n, dim) into the domain along the periodic axes, in place
        (``x <- lo + (x - lo) mod L``); ``follow`` (n, dim) moves by the same whole periods.
        Returns how many coordinates moved. Nothing to do (and no pass over x) without
        periodic axes."""
        if not self._any_periodic or not len(x):
            return 0
        if follow is None:
            follow = np.empty((0, self.dim))
        return int(wrap_periodic(x, self.domain_lo, self.inv_dx, self.dx, self.period, follow))

    def wrap_particles(self, particles) -> int:
        """`wrap` the particles' positions; their reference positions (the field
        ``FOLLOWS_WRAPS``, where the particles carry it: peridynamic and SPB materials) move
        by the same whole periods, so a bond's reference vector between a particle and a
        copy of its partner stays what it was, however far the body travels."""
        follow = particles[FOLLOWS_WRAPS] if FOLLOWS_WRAPS in particles else None
        return self.wrap(particles["x"], follow)

    def owners(self, x: np.ndarray) -> np.ndarray:
        """Owning rank of each position x (n, dim) (of its periodic image in the domain)."""
        out = np.empty(len(x), dtype=np.int64)
        x = np.array(x, dtype=np.float64)  # a copy: wrapping must not move the caller's x
        self.wrap(x)
        return owner_ranks(x, self.domain_lo, self.inv_dx, self.boxes, self.rank, out)

    def _reduce_max(self, a: np.ndarray) -> np.ndarray:
        out = np.empty_like(a)
        self.mpi.Allreduce(np.ascontiguousarray(a), out, op=MPI.MAX)
        return out

    def _reduce_sum(self, a: np.ndarray) -> np.ndarray:
        out = np.empty_like(a)
        self.mpi.Allreduce(np.ascontiguousarray(a), out, op=MPI.SUM)
        return out

    def max_then_sum(self, maxes, sums) -> tuple[np.ndarray, np.ndarray]:
        """Global elementwise max of ``maxes`` and sum of ``sums`` (floats; integers below
        2**53 exactly) in one allreduce of ``len(maxes) + len(sums) + 1`` doubles."""
        k = len(maxes)
        vec = np.concatenate([[k], np.asarray(maxes, np.float64), np.asarray(sums, np.float64)])
        out = np.empty_like(vec)
        self.mpi.Allreduce(vec, out, op=max_then_sum_op())
        return out[1:k + 1], out[k + 1:]

    # -- the step's agreement -----------------------------------------------------------------
    def agree(self, particles, speed: float, n_bad: int) -> tuple[float, int]:
        """The one global reduction of an ordinary step (the health check before it): the
        largest particle speed (the time step), the number of broken particles (the
        instability guard), whether any rank has a stop request (``stop_requested``, the
        run loop's signal; the answer is ``stop_agreed``) and whether any rank holds particles
        that jumped past its neighbours (then they are delivered here, `migrate_all`, and
        ``moved_in_agree`` counts the particles this rank sent and received: the caller's
        particle order is then stale). One allreduce of 5 doubles. Returns (max speed, total
        broken)."""
        maxes, sums = self.max_then_sum(
            [speed, float(self.pending_far > 0), float(self.stop_requested)], [n_bad])
        self.stop_agreed = bool(maxes[2])
        self.moved_in_agree = 0
        if maxes[1]:
            arrived_before = self.arrived
            self.moved_in_agree = self.migrate_all(particles) + self.arrived - arrived_before
        return float(maxes[0]), int(sums[0])

    # -- particles ----------------------------------------------------------------------------
    def migrate(self, particles) -> int:
        """The step's migration: particles that left my box go to their owner when it is a
        neighbour (one message per neighbour with any, the counts by one neighbour
        all-to-all); a particle that jumped further stays here, counted in ``pending_far``,
        until the next `agree` delivers it. Returns the number sent.

        Positions are wrapped into the domain along the periodic axes first (G2P moved them
        freely): this is the one place a step does it, so P2G, the owner lookup, frames and
        checkpoints all see wrapped positions."""
        self.wrap_particles(particles)
        if self.size == 1:
            return 0
        graph = self._neighbour_graph()
        leaving = np.empty(particles.n, dtype=np.int64)
        owner = np.empty(particles.n, dtype=np.int64)
        k = leavers(particles["x"], self.domain_lo, self.inv_dx, self.boxes, self._search,
                    leaving, owner)
        leaving, owner = leaving[:k], owner[:k]
        near = np.isin(owner, self.neighbours)
        self.pending_far = int(k - near.sum())
        leaving = leaving[near]
        slot = np.searchsorted(self.neighbours, owner[near])  # position in the graph
        order = leaving[np.argsort(slot, kind="stable")]
        send_counts = np.bincount(slot, minlength=len(self.neighbours)).astype(np.int64)
        recv_counts = np.empty(len(self.neighbours), dtype=np.int64)
        graph.Neighbor_alltoall(send_counts, recv_counts)
        return self._move(particles, order, self.neighbours, send_counts, self.neighbours,
                          recv_counts)

    def migrate_all(self, particles, batch: int | None = None) -> int:
        """Send every particle whose owner changed to its owner, whichever rank that is
        (collective: one all-to-all of counts per round). ``batch`` bounds the particles a
        rank sends per round (start-up, where most particles move: the buffers in flight stay
        at ``batch`` rows); rounds go on until no rank has leavers left."""
        self.wrap_particles(particles)
        self.pending_far = 0
        if self.size == 1:
            return 0
        ranks = np.arange(self.size, dtype=np.int64)
        everybody = np.concatenate([[self.rank], ranks[ranks != self.rank]])
        sent = 0
        while True:
            leaving = np.empty(particles.n, dtype=np.int64)
            owner = np.empty(particles.n, dtype=np.int64)
            k = leavers(particles["x"], self.domain_lo, self.inv_dx, self.boxes, everybody,
                        leaving, owner)
            take = k if batch is None else min(k, batch)
            leaving, owner = leaving[:take], owner[:take]
            order = leaving[np.argsort(owner, kind="stable")]
            del leaving
            send_counts = np.bincount(owner, minlength=self.size).astype(np.int64)
            recv_counts = np.empty(self.size, dtype=np.int64)
            self.mpi.Alltoall(send_counts, recv_counts)
            sent += self._move(particles, order, ranks, send_counts, ranks, recv_counts)
            if batch is None or not self.any(k - take > 0):
                return sent

    def _move(self, particles, order, dests, send_counts, sources, recv_counts) -> int:
        """Pack rows ``order`` (grouped by destination), exchange, remove, append."""
        if not len(order) and not recv_counts.any():
            return 0
        arrays = {name: particles[name] for name in particles.field_names()}
        send = pack_rows(arrays, order, row_dtype(arrays))
        # Views of the old field arrays would keep them alive if `append` has to grow them.
        del arrays
        recv = exchange_rows(self.mpi, send, dests, send_counts, sources, recv_counts,
                             TAG_MIGRATE)
        self.arrived += len(recv)
        del send
        if len(order):
            particles.remove(order)
        if len(recv):
            particles.append(unpack_rows(recv))
        return int(len(order))

    def global_count(self, particles) -> int:
        return int(self.sum(int(particles.n)))

    def particle_halo(self, particles, r: float, names) -> dict[str, np.ndarray]:
        """Read-only copies of other ranks' particles within ``r`` of my owned region (its box in
        physical coordinates, expanded by ``r``), for the fields ``names``.

        Across a periodic face a copy is the particle's image: its ``x`` (when asked for) is
        shifted by the period, so the receiver sees it where it acts; a rank receives images of
        its own particles too when its box is within ``r`` of itself across the face. ``r``
        must stay below every period. The neighbour test (box gap ``<= r``, per image) is
        symmetric, so both sides agree on who talks to whom and the counts go point-to-point
        too. Rows arrive grouped by source rank, each source's images in `shifts` order."""
        names = list(names)
        length = self.period * self.dx
        if np.any(self.periodic & (r >= length)):
            raise ValueError(f"particle halo reach {r} must be below the period "
                             f"{length[self.periodic].min()} of every periodic axis")
        arrays = {name: particles[name] for name in names}
        lo = self.domain_lo + self.boxes[:, 0].astype(np.float64) * self.dx
        hi = self.domain_lo + self.boxes[:, 1].astype(np.float64) * self.dx
        me = self.rank
        shifts = self.shifts * self.dx  # physical image offsets
        # (q, s): rank q sees my particles at x + shifts[s]; those lie in its expanded box.
        pairs = [(q, s) for s in range(len(shifts))
                 for q in np.flatnonzero(np.max(np.maximum(lo - shifts[s] - hi[me],
                                                           lo[me] - hi + shifts[s]), axis=1) <= r)
                 if q != me or s]
        pairs.sort()
        q_of = np.array([q for q, _ in pairs], dtype=np.int64)
        offset = np.array([shifts[s] for _, s in pairs]).reshape(len(pairs), self.dim)
        counts, index = points_in_boxes(particles["x"], lo[q_of] - offset - r,
                                        hi[q_of] - offset + r)
        ranks = np.unique(q_of)
        send_counts = np.zeros(len(ranks), dtype=np.int64)
        np.add.at(send_counts, np.searchsorted(ranks, q_of), counts)
        recv_counts = send_counts.copy()  # my own images: what I send myself
        others = np.flatnonzero(ranks != me)
        requests = [self.mpi.Irecv(recv_counts[i:i + 1], source=int(ranks[i]),
                                   tag=TAG_HALO_COUNT) for i in others]
        requests += [self.mpi.Isend(send_counts[i:i + 1], dest=int(ranks[i]),
                                    tag=TAG_HALO_COUNT) for i in others]
        MPI.Request.Waitall(requests)
        send = pack_rows(arrays, index, row_dtype(arrays))
        if "x" in arrays and self.periodic.any():
            send["x"] += np.repeat(offset, counts, axis=0)
        recv = exchange_rows(self.mpi, send, ranks, send_counts, ranks, recv_counts, TAG_HALO)
        return {name: np.ascontiguousarray(a) for name, a in unpack_rows(recv).items()}

    # -- load balance -------------------------------------------------------------------------
    def imbalance(self, particles, weights: np.ndarray | None = None) -> float:
        """max / mean load over ranks: the particle count, or the sum of ``weights`` (n,)
        (1.0 when there is none); one allreduce of 3 doubles."""
        load = particles.n if weights is None else int(np.sum(weights))
        maxes, sums = self.max_then_sum([load], [load])
        mean = sums[0] / self.size
        return float(maxes[0] / mean) if mean > 0 else 1.0

    def rebalance(self, particles, threshold: float = 1.2,
                  weights: np.ndarray | None = None) -> bool:
        """Recompute the bisection and migrate when ``imbalance > threshold`` (both by
        ``weights`` when given). Every rank takes the same branch (the imbalance is global).
        Only moves particles, so results change by round-off at most (summation order of the
        grid halo)."""
        if self.size == 1 or self.imbalance(particles, weights) <= threshold:
            return False
        self.decompose(particles, weights=weights)
        return True

    # -- grid ---------------------------------------------------------------------------------
    def grid_box(self, particles, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """Node box ``(lo, hi)`` this rank's GridBlock must hold: the support of its particles
        plus the owned nodes that other ranks' particles touch (empty, ``lo == hi``, when
        neither exists). The support boxes (2*dim ints) go to the neighbours only (a neighbour
        all-gather); the exchange plan is rebuilt when mine or theirs changed. ``order`` is
        accepted for both kernels: the support (cell - 1 .. cell + 2) is the same.

        My particles lie in my box (`migrate` ends every step, `agree` delivers far jumps), so
        the support stays within `NEIGHBOUR_REACH` cells of it, where my neighbours' boxes
        are; a support beyond that means particles are on the wrong rank (an error)."""
        support = np.zeros((2, self.dim), dtype=np.int64)
        lo, hi = np.empty(self.dim, np.int64), np.empty(self.dim, np.int64)
        if cell_bounds(particles["x"], self.domain_lo, self.inv_dx, lo, hi):
            support[0] = lo - GHOST_BELOW
            support[1] = hi + GHOST_ABOVE + 1
            own_lo, own_hi = self.boxes[self.rank]
            if np.any(support[0] < own_lo - NEIGHBOUR_REACH) or \
                    np.any(support[1] > own_hi + NEIGHBOUR_REACH):
                raise RuntimeError(
                    f"rank {self.rank}: particles outside its box (cells {lo.tolist()} .. "
                    f"{hi.tolist()}, box {own_lo.tolist()} .. {own_hi.tolist()}): call "
                    f"domain.migrate and domain.agree (the health check) before the step")
        if self.size == 1:
            key = support.tobytes()
            theirs = np.empty((0, 2, self.dim), dtype=np.int64)
        else:
            theirs = np.empty((len(self._neighbour_graph_ready()), 2, self.dim), np.int64)
            self._graph.Neighbor_allgather(support, theirs)
            key = support.tobytes() + theirs.tobytes()
        if self._plan is None or self._plan.key != key:
            self._plan = self._grid_plan(support, theirs, key)
        return self._plan.block_lo.copy(), self._plan.block_hi.copy()

    def _neighbour_graph_ready(self) -> np.ndarray:
        self._neighbour_graph()
        return self.neighbours

    def _grid_plan(self, support: np.ndarray, theirs: np.ndarray, key: bytes) -> GridPlan:
        """Exchange regions from the support boxes: for each neighbour (and myself) ``r`` and
        image shift ``s`` (zero only when no axis is periodic), ``support(me) & (owned(r) +
        s)`` are my partial sums of ``r``'s nodes (``r`` adds them at ``- s``) and
        ``(support(r) - s) & owned(me)`` my owned nodes that ``r``'s particles touch through
        that image."""
        me = self.rank
        own_lo, own_hi = self.boxes[me]
        to_owners, from_touchers = [], []
        parts = []
        if not is_empty(*support):
            parts.append(support)
        ranks = [(int(r), theirs[i]) for i, r in enumerate(self.neighbours)] + [(me, support)]
        for r, support_r in sorted(ranks, key=lambda item: item[0]):
            sends, recvs = [], []
            for s in self.shifts:
                if r == me and not s.any():
                    continue
                lo, hi = intersect(*support, *(self.boxes[r] + s))
                if not is_empty(lo, hi):
                    sends.append((lo, hi))
                lo, hi = intersect(*(support_r - s), own_lo, own_hi)
                if not is_empty(lo, hi):
                    recvs.append((lo, hi))
                    parts.append((lo, hi))
            if sends:
                to_owners.append((r, sends))
            if recvs:
                from_touchers.append((r, recvs))
        if parts:
            block_lo = np.min([p[0] for p in parts], axis=0)
            block_hi = np.max([p[1] for p in parts], axis=0)
        else:
            block_lo = block_hi = np.zeros(self.dim, dtype=np.int64)
        return GridPlan(key, block_lo, block_hi, to_owners, from_touchers)

    def _require_plan(self) -> GridPlan:
        if self._plan is None:
            raise RuntimeError("call domain.grid_box(particles, order) before a grid exchange")
        return self._plan

    def _region_nodes(self, regions, grid) -> np.ndarray:
        """The block's flat node indices of a plan's region list: region by region, each in
        C order (`region_slices`), remembered for the plan and block. The semi-implicit
        solve exchanges ghosts twice per CG iteration, where recomputing the slices cost a
        third of a small scene's solve (measured: 2048-particle channel, 1 rank). Keyed by
        the region list's identity, which the cached plan keeps alive, and the block's
        origin and shape."""
        plan = self._plan
        if self._boxes_plan is not plan:
            self._boxes_plan = plan
            self._boxes_cache = {}
        key = (id(regions), tuple(grid.origin.tolist()), tuple(grid.shape))
        index = self._boxes_cache.get(key)
        if index is None:
            if len(self._boxes_cache) >= 64:  # a block that keeps moving: bound the memory
                self._boxes_cache.clear()
            flat = np.arange(math.prod(grid.shape), dtype=np.int64).reshape(grid.shape)
            parts = [flat[region_slices(lo, hi, grid.origin, grid.shape)].reshape(-1)
                     for lo, hi in regions]
            index = np.concatenate(parts) if parts else np.empty(0, dtype=np.int64)
            self._boxes_cache[key] = index
        return index

    def _exchange_regions(self, grid, names, sends, recvs, tag: int, add: bool) -> None:
        """One message per neighbour holding all its regions, field after field; a rank's
        regions on itself (a periodic image of its own nodes) are copied, not sent.
        Everything is packed before anything is unpacked, so a self copy reads the values
        from before the exchange. Packing and unpacking are kernels over the regions' node
        lists (`gather_nodes`, `scatter_nodes`): numpy slicing region by region cost more
        than the exchange itself on a small block."""
        if not sends and not recvs:     # one rank, no periodic axis: nothing to exchange
            return
        # Each field as (nodes, values per node): views of the contiguous block.
        nodes = math.prod(grid.shape)
        fields = [grid[name].reshape(nodes, math.prod(grid[name].shape[self.dim:]))
                  for name in names]
        per_node = sum(f.shape[1] for f in fields)
        requests, received, local = [], [], {}
        for r, regions in recvs:
            index = self._region_nodes(regions, grid)
            buf = None
            if r != self.rank:
                buf = np.empty(index.size * per_node, dtype=np.float64)
                requests.append(self.mpi.Irecv(buf, source=r, tag=tag))
            received.append((r, index, buf))
        for r, regions in sends:
            index = self._region_nodes(regions, grid)
            buf = np.empty(index.size * per_node, dtype=np.float64)
            start = 0
            for f in fields:
                gather_nodes(f, index, buf, start)
                start += index.size * f.shape[1]
            if r == self.rank:
                local[r] = buf
            else:
                requests.append(self.mpi.Isend(buf, dest=r, tag=tag))
        MPI.Request.Waitall(requests)
        for r, index, buf in received:  # in rank order: a deterministic summation order
            buf = local[r] if buf is None else buf
            start = 0
            for f in fields:
                scatter_nodes(f, index, buf, start, add)
                start += index.size * f.shape[1]

    def sum_ghosts_to_owners(self, grid, *names: str) -> None:
        """After P2G: each rank sends its partial sums on nodes owned by others to the owners,
        which add them. Several fields travel in one message per neighbour."""
        plan = self._require_plan()
        self._exchange_regions(grid, names, plan.to_owners, plan.from_touchers, TAG_SUM, True)

    def fill_ghosts(self, grid, *names: str) -> None:
        """After the grid update: owners send the final values of the nodes other ranks'
        particles touch; those ranks overwrite their ghost copies."""
        plan = self._require_plan()
        self._exchange_regions(grid, names, plan.from_touchers, plan.to_owners, TAG_FILL, False)

    def owned_slices(self, grid) -> tuple:
        """Slices of the block (``grid.lo .. grid.hi``) that this rank owns."""
        lo, hi = intersect(np.asarray(grid.lo), np.asarray(grid.hi), *self.boxes[self.rank])
        hi = np.maximum(hi, lo)
        return tuple(slice(int(l - o), int(h - o)) for l, h, o in zip(lo, hi, grid.origin))

    def dot(self, grid, a: str, b: str) -> float:
        """sum over owned nodes of a . b (scalar or vector fields), reduced over ranks."""
        s = self.owned_slices(grid)
        return float(self.sum(float(np.vdot(grid[a][s], grid[b][s]))))

    def dots(self, grid, pairs, weights=None) -> np.ndarray:
        """Several dot products of grid fields in one allreduce (the conjugate gradient's
        reductions of one iteration): ``out[k] = sum_i m_i^weights[k] a_k(i) . b_k(i)`` over
        this rank's owned nodes that have mass, summed over ranks, for ``pairs[k] = (a, b)``
        field names (scalar or vector); ``weights[k]`` is 0 (default), 1 or 2. No grid vector
        leaves its rank: each rank sends one partial sum per pair."""
        from ..kernels.implicit import owned_dot

        # The owned range in the block, remembered while the boxes and the block stay (a CG
        # iteration calls this once, at a cost beside its kernels on a small scene).
        key = (self.boxes, (grid.lo.tolist(), grid.hi.tolist(), grid.origin.tolist()))
        cached = self._dots_range
        if cached is None or cached[0] is not key[0] or cached[1] != key[1]:
            s = self.owned_slices(grid)
            lo = np.zeros(3, dtype=np.int64)
            hi = np.ones(3, dtype=np.int64)
            lo[: self.dim] = [sl.start for sl in s]
            hi[: self.dim] = [sl.stop for sl in s]
            cached = self._dots_range = key + (lo, hi)
        lo, hi = cached[2], cached[3]
        shape3 = tuple(grid.shape) + (1,) * (3 - self.dim)
        mass = grid["mass"].reshape(shape3)
        weights = weights or (0,) * len(pairs)
        local = np.array([owned_dot(grid[a].reshape(shape3 + (-1,)),
                                    grid[b].reshape(shape3 + (-1,)), mass, int(w), lo, hi)
                          for (a, b), w in zip(pairs, weights)])
        return self._reduce_sum(local)

    def weighted_sum(self, grid, name: str, power: int) -> tuple[np.ndarray, float]:
        """(sum_i m_i^power a_i, sum_i m_i^power) over the owned nodes of all ranks (power 1
        or 2: nodes without mass add nothing) for the grid field ``name``; one allreduce of
        c + 1 doubles."""
        s = self.owned_slices(grid)
        m = grid["mass"][s]
        a = grid[name][s]
        components = a.shape[m.ndim] if a.ndim > m.ndim else 1
        if power not in (1, 2):
            raise ValueError(f"weighted_sum: power {power} is not 1 or 2")
        w = (m * m if power == 2 else m).reshape(-1)
        # A rank without particles has an empty block.
        local = np.append(w @ a.reshape(-1, components), w.sum())
        total = self._reduce_sum(local)
        return total[:-1], float(total[-1])

    # -- failure ------------------------------------------------------------------------------
    def install_abort_hook(self) -> None:
        """Make an uncaught exception on any rank abort all ranks (after printing it), instead
        of leaving the others waiting in a collective forever. No-op on one rank."""
        if self.size == 1:
            return
        previous = sys.excepthook
        comm = self.comm

        def abort_on_exception(exc_type, exc, tb):
            previous(exc_type, exc, tb)
            sys.stderr.flush()
            sys.stdout.flush()
            # MPI_Abort also ends the launcher's forwarding of this rank's output: give it a
            # moment to pass the traceback on (on a loaded host only its first line came out).
            time.sleep(ABORT_GRACE_S)
            comm.Abort(1)

        sys.excepthook = abort_on_exception


__all__ = ["Domain", "GridPlan", "BIG"]

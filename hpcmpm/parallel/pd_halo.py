"""Peridynamic bonds across ranks: a reusable particle-halo plan and bond migration.

Reach. A bond p-q with p owned here is intact only while its stretch s <= s_reach (the
critical stretch, or the scene's ``max_bond_stretch``, beyond which every model breaks it), so
its partner lies within ``reach = radius (1 + s_reach)`` of the owned box (radius: the family
search radius, delta + dx/2 with partial volumes). The plan ships every PD particle within
``reach + skin`` of each neighbour's box (periodic images shifted by the period, when the
domain has periodic axes) and is reused until some particle moved more than skin/2 since it
was built, or PD particles changed rank. Between rebuilds only values are refreshed along the
same send lists. A partner missing from the halo is then more than ``reach`` away, so its bond
has s > s_reach and breaks at any rank count (the model kernels treat slot -1 so): no bond is
ever dropped because of the decomposition (LAMMPS PERI drops them, pair_peri_*.cpp).

Migration. `migrate_with_bonds` sends each leaving particle's bond segment (partner ids,
status, weights, per-bond state) to its new owner alongside `Domain.migrate`, and realigns
the bond rows with the particle rows by id. `redistribute_segments` does the same after the
fact, for particles that moved by a route that does not know about bonds (the engine's
migration and rebalancing): the ranks that miss segments name the ids, their old holders send
them.
"""

from __future__ import annotations

import numpy as np

from .decomposition import points_in_boxes
from .exchange import exchange_rows, pack_rows, row_dtype, unpack_rows

TAG_PD_HALO, TAG_PD_SEGMENTS, TAG_PD_BONDS = 111, 112, 113


def _exchange(comm, send, send_counts, recv_counts, tag):
    """`exchange.exchange_rows` with counts per rank (rows grouped by rank), whichever of its
    two signatures this tree has: (send_counts, recv_counts) per rank, or the per-neighbour
    lists of the periodic-axes version (dests, send_counts, sources, recv_counts)."""
    if exchange_rows.__code__.co_argcount == 5:
        return exchange_rows(comm, send, send_counts, recv_counts, tag)
    ranks = np.arange(len(send_counts))
    return exchange_rows(comm, send, ranks, send_counts, ranks, recv_counts, tag)


class PDHalo:
    """The PD particle halo of one rank.

    Parameters
    ----------
    domain : the `Domain` (boxes, communicator, and periodic ``shifts`` when it has them).
    reach : radius (1 + s_reach): the farthest an intact bond's partner can be.
    skin : extra distance shipped so the plan survives motions up to skin / 2.
    shifted : names of fields that are positions (an image adds the period to them).
    """

    def __init__(self, domain, reach: float, skin: float, shifted=("x", "x0")):
        self.domain = domain
        self.reach = float(reach)
        self.skin = float(skin)
        self.shifted = tuple(shifted)
        self.builds = 0
        self.send_index = np.empty(0, np.int64)
        self.send_shift = np.empty((0, domain.dim))
        self.send_counts = np.zeros(domain.size, np.int64)
        self.recv_counts = np.zeros(domain.size, np.int64)
        self.x_built = np.empty((0, domain.dim))

    @property
    def n_halo(self) -> int:
        return int(self.recv_counts.sum())

    def build(self, x: np.ndarray, fields: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Plan the halo from my PD particles' positions ``x`` (n, d) and ship ``fields``
        (per-particle arrays, e.g. id, x, x0, vol) once. Collective. Returns the halo copies,
        grouped by source rank."""
        d = self.domain
        r = self.reach + self.skin
        lo = d.domain_lo + d.boxes[:, 0].astype(np.float64) * d.dx
        hi = d.domain_lo + d.boxes[:, 1].astype(np.float64) * d.dx
        shifts = getattr(d, "shifts", np.zeros((1, d.dim), np.int64)) * d.dx
        me = d.rank
        pairs = [(q, s) for q in range(d.size) for s in range(len(shifts))
                 if (q != me or shifts[s].any())
                 and np.max(np.maximum(lo[q] - shifts[s] - hi[me],
                                       lo[me] - hi[q] + shifts[s])) <= r]
        q_of = np.array([q for q, _ in pairs], dtype=np.int64)
        offset = np.array([shifts[s] for _, s in pairs], dtype=np.float64).reshape(-1, d.dim)
        counts, index = points_in_boxes(np.ascontiguousarray(x), lo[q_of] - offset - r,
                                        hi[q_of] - offset + r)
        self.send_index = index
        self.send_shift = np.repeat(offset, counts, axis=0)
        self.send_counts = np.bincount(q_of, weights=counts, minlength=d.size).astype(np.int64)
        self.recv_counts = np.empty(d.size, np.int64)
        d.comm.Alltoall(self.send_counts, self.recv_counts)
        self.x_built = np.array(x, dtype=np.float64, copy=True)
        self.builds += 1
        return self.refresh(fields)

    def stale(self, x: np.ndarray) -> bool:
        """True on every rank when some PD particle moved more than skin/2 since the build.
        Collective."""
        moved = 0.0
        if len(x) and len(x) == len(self.x_built):
            moved = float(np.sqrt(((x - self.x_built) ** 2).sum(axis=1)).max())
        elif len(x) != len(self.x_built):
            moved = np.inf
        return bool(self.domain.max(moved) > 0.5 * self.skin)

    def refresh(self, fields: dict[str, np.ndarray], out: dict[str, np.ndarray] | None = None
                ) -> dict[str, np.ndarray]:
        """Current values of ``fields`` (per-particle arrays of my PD rows) for the halo rows,
        along the plan's send lists. Writes into ``out[name]`` (n_halo, ...) when given.
        Collective."""
        arrays = {k: np.ascontiguousarray(v) for k, v in fields.items()}
        send = pack_rows(arrays, self.send_index, row_dtype(arrays))
        for name in self.shifted:
            if name in arrays and len(send):
                send[name] += self.send_shift
        recv = _exchange(self.domain.comm, send, self.send_counts, self.recv_counts, TAG_PD_HALO)
        got = unpack_rows(recv)
        if out is None:
            return {k: np.ascontiguousarray(v) for k, v in got.items()}
        for k, v in got.items():
            out[k][...] = v
        return out

    def homes(self, x0: np.ndarray) -> np.ndarray:
        """My rows' reference positions ``x0`` followed by the halo rows' own, not moved by
        the period (an image's shipped x0 differs from its home by whole periods:
        `find_families` reads a bond's periods from that difference). Collective."""
        return np.concatenate([x0, self.refresh({"home": x0})["home"]])

    def refresh_rows(self, n_owned: int):
        """A callable refreshing the halo rows (n_owned..) of arrays over owned + halo rows
        from their owned rows."""
        def refresh(arrays: dict[str, np.ndarray]) -> None:
            self.refresh({k: a[:n_owned] for k, a in arrays.items()},
                         {k: a[n_owned:] for k, a in arrays.items()})
        return refresh


def send_segments(domain, bonds, row_ids, rows, dest):
    """Send the segments of bond rows ``rows`` (ids ``row_ids[rows]``) to ranks ``dest``
    (grouped by destination); returns (ids, counts, arrays) received, grouped by source."""
    counts, arrays = bonds.extract(rows)
    seg_send = np.bincount(dest, minlength=domain.size).astype(np.int64)
    bond_send = np.bincount(np.repeat(dest, counts), minlength=domain.size).astype(np.int64)
    seg_recv = np.empty(domain.size, np.int64)
    bond_recv = np.empty(domain.size, np.int64)
    domain.comm.Alltoall(seg_send, seg_recv)
    domain.comm.Alltoall(bond_send, bond_recv)
    seg = {"id": np.asarray(row_ids)[rows], "count": counts}
    got_seg = unpack_rows(_exchange(domain.comm, pack_rows(seg, np.arange(len(rows)),
                                                           row_dtype(seg)),
                                    seg_send, seg_recv, TAG_PD_SEGMENTS))
    arrays = {k.replace(".", "__"): v for k, v in arrays.items()}
    got = unpack_rows(_exchange(domain.comm, pack_rows(arrays, np.arange(int(counts.sum())),
                                                       row_dtype(arrays)),
                                bond_send, bond_recv, TAG_PD_BONDS))
    return (np.ascontiguousarray(got_seg["id"]), np.ascontiguousarray(got_seg["count"]),
            {k.replace("__", "."): np.ascontiguousarray(v) for k, v in got.items()})


def migrate_with_bonds(domain, particles, bonds) -> int:
    """`Domain.migrate` for a set whose rows all carry bonds: each leaver's bond segment goes
    to its new owner; afterwards ``bonds`` rows follow ``particles`` rows (matched by id).
    Returns the number of particles that changed rank on any rank (collective)."""
    me = domain.rank
    ids = particles["id"].copy()      # migrate reorders the rows in place
    dest = domain.owners(particles["x"]) if domain.size > 1 else np.full(len(ids), me)
    leaving = np.flatnonzero(dest != me)
    order = leaving[np.argsort(dest[leaving], kind="stable")]
    domain.migrate(particles)
    total = int(domain.sum(int(len(order))))
    if total == 0:
        return 0
    got_ids, got_counts, got = send_segments(domain, bonds, ids, order, dest[order])
    stay = np.ones(len(ids), dtype=bool)
    stay[order] = False
    bonds.keep(stay)
    bonds.append(got_counts, got)
    align_rows(bonds, np.concatenate([ids[stay], got_ids]), particles["id"])
    return total


def redistribute_segments(domain, bonds, row_ids: np.ndarray, target_ids: np.ndarray
                          ) -> np.ndarray:
    """After particles moved between ranks by any route (migration, rebalance, restart):
    each rank sends the segments of rows it no longer holds to the ranks that now hold those
    particles, then the bond rows follow ``target_ids`` (this rank's PD particle ids in row
    order). Collective; only the ids of the arrivals travel to every rank. Returns the new
    row ids (= target_ids)."""
    row_ids = np.asarray(row_ids, dtype=np.int64)
    target_ids = np.asarray(target_ids, dtype=np.int64)
    missing = np.setdiff1d(target_ids, row_ids)
    wanted = domain.allgather(missing)
    orphan = ~np.isin(row_ids, target_ids)
    rows, dest = [], []
    for r, ids_r in enumerate(wanted):
        if r == domain.rank or not len(ids_r):
            continue
        hit = np.flatnonzero(orphan & np.isin(row_ids, ids_r))
        rows.append(hit)
        dest.append(np.full(len(hit), r, np.int64))
    rows = np.concatenate(rows) if rows else np.empty(0, np.int64)
    dest = np.concatenate(dest) if dest else np.empty(0, np.int64)
    got_ids, got_counts, got = send_segments(domain, bonds, row_ids, rows, dest)
    bonds.keep(~orphan)
    bonds.append(got_counts, got)
    align_rows(bonds, np.concatenate([row_ids[~orphan], got_ids]), target_ids)
    return target_ids.copy()


def route_half_bonds(domain, arrays: dict[str, np.ndarray], owner_ids: np.ndarray
                     ) -> dict[str, np.ndarray]:
    """Send half-bond rows (``arrays["owner"]``: the global id of the row's owner particle)
    to the rank that holds that particle now (``owner_ids``: this rank's PD particle ids).
    For restarts: the ids of every rank are gathered once. Collective."""
    held = domain.allgather(np.asarray(owner_ids, np.int64))
    ids = np.concatenate(held)
    ranks = np.repeat(np.arange(domain.size), [len(h) for h in held])
    order = np.argsort(ids, kind="stable")
    owner = np.asarray(arrays["owner"], np.int64)
    pos = np.searchsorted(ids, owner, sorter=order)
    if len(owner) and (np.any(pos >= len(ids)) or np.any(ids[order[np.minimum(
            pos, len(ids) - 1)]] != owner)):
        raise RuntimeError("a checkpointed bond names a particle no rank holds")
    dest = ranks[order[pos]] if len(owner) else np.empty(0, np.int64)
    rows = np.argsort(dest, kind="stable")
    send_counts = np.bincount(dest, minlength=domain.size).astype(np.int64)
    recv_counts = np.empty(domain.size, np.int64)
    domain.comm.Alltoall(send_counts, recv_counts)
    packed = {k.replace(".", "__"): np.ascontiguousarray(v) for k, v in arrays.items()}
    got = unpack_rows(_exchange(domain.comm, pack_rows(packed, rows, row_dtype(packed)),
                                send_counts, recv_counts, TAG_PD_BONDS))
    return {k.replace("__", "."): np.ascontiguousarray(v) for k, v in got.items()}


def align_rows(bonds, row_ids: np.ndarray, target_ids: np.ndarray) -> None:
    """Permute ``bonds`` (rows named by ``row_ids``) into the order ``target_ids``."""
    sorter = np.argsort(row_ids, kind="stable")
    found = np.searchsorted(row_ids, target_ids, sorter=sorter)
    # An id beyond every held one (or none held) is found at len(row_ids): the same error.
    if len(target_ids) and (not len(row_ids) or found.max() >= len(row_ids)):
        raise RuntimeError("bond rows and particle rows hold different ids")
    pos = sorter[found]
    if not np.array_equal(row_ids[pos], target_ids):
        raise RuntimeError("bond rows and particle rows hold different ids")
    bonds.permute(pos)


__all__ = ["PDHalo", "migrate_with_bonds", "redistribute_segments", "route_half_bonds",
           "align_rows"]

"""Peridynamic bonds: a side structure of half-bonds in CSR, not a particle field.

Each owned PD particle ``i`` holds its half-bonds ``offsets[i]:offsets[i+1]``; both ends of a
bond hold one half-bond each, and both evaluate the bond from the same inputs (see the model
kernels), so a bond that crosses a rank boundary needs no reverse communication. Partners are
named by their permanent global id and each segment is ordered by it, so a particle sums its
bonds in the same order on any rank count. MPM-only particles carry nothing.

Resident bytes per half-bond (`Bonds.resident_bytes_per_bond`):

=========  =======  ==================================================================
array      dtype    meaning
=========  =======  ==================================================================
partner    int64    global id of the other end (permanent; migrates and checkpoints)
weight     float64  omega(|X|) * beta: influence function times the partial-volume
                    fraction of the partner (fixed in the reference configuration)
slot       int32    local row of the partner in the (owned + halo) point arrays; rebuilt
                    with the halo plan, -1 when unresolved (allowed for broken bonds only)
status     int8     1 intact, 0 broken (irreversible, 003 eq. 4.8)
image      int8     which periodic image of the partner (`image_label` of the reference
                    bond; 0 for the minimum image, and so without periodic axes)
=========  =======  ==================================================================

22 B in all, plus 8 B per optional per-bond float64 state array (`state`, e.g. a plastic
bond stretch or a viscous force for the models that need them) and 8 B per particle for
``offsets``. The reference bond ``X`` is not stored: it is ``x0[slot] - x0[i]`` from the
reference positions that the halo carries anyway (correspondence needs the vector), and both
ends recompute it bit-identically (negating a difference is exact).

Periodic images. Along a periodic axis of period P a family of radius r < P can hold two
images of one partner (a reference offset d and d - P, both shorter than r, once r > P/2):
two half-bonds with one partner id, told apart by ``image``, a label of the reference bond
vector X that reference positions following their particle by whole periods leave unchanged
(`image_label`). A segment is ordered by (partner, image), and `resolve_slots` gives each
half-bond the halo copy with its label (a partner bonded once whose label no copy has takes
its nearest copy, the rule before labels).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

INTACT, BROKEN = np.int8(1), np.int8(0)
# The arrays every half-bond has, in the order segments are packed for migration/checkpoints
# (``image`` too; where a caller has none to give, as for an SPB conversion, it is 0).
CORE_BOND_FIELDS = ("partner", "weight", "status")
# A reference offset of exactly half a period (a lattice with an even number of rows across
# it) has two images at equal length; the bias puts +P/2 and -P/2 in different labels
# whatever the round-off of the positions (1e-6 of a period: far below the 1/(2N) by which
# a lattice of N rows across a period can come near the edge, far above round-off).
_LABEL_BIAS = 1e-6


@njit(cache=True, error_model="numpy")
def image_label(X, period):
    """The periodic image a reference bond vector ``X`` (d,) reaches, as one small integer:
    per periodic axis n_a = floor(X_a / P_a + 1/2 + bias) in {-1, 0, 1} for |X_a| < P_a (the
    family radius is below the period), coded sum_a (n_a mod 3) 3^a, so the minimum image
    (every |X_a| below half the period) is 0, the label of a half-bond made without one;
    axes with P_a = 0 count 0. Two images of one partner differ by a whole period along
    some axis, so their labels differ; X itself, and so the label, does not change when a
    particle's reference position follows it across a periodic face by a whole period.
    An offset of a period and a half or more on some axis (a copy two periods away, which
    the halo of an axis narrower than its reach holds) is no bond's: -1, matching none."""
    code = 0
    scale = 1
    for a in range(len(X)):
        if period[a] > 0.0:
            n = math.floor(X[a] / period[a] + 0.5 + _LABEL_BIAS)
            if n < -1 or n > 1:
                return -1
            code += (n % 3) * scale
        scale *= 3
    return code


class Bonds:
    """Half-bonds of ``n`` particles in CSR.

    Parameters
    ----------
    offsets : (n + 1,) int64, segment starts.
    partner : (nb,) int64 global ids, ascending within each segment.
    weight : (nb,) float64, omega * beta.
    status : (nb,) int8, 1 intact / 0 broken (default all intact).
    slot : (nb,) int32 local partner rows (default -1: resolve with `resolve_slots`).
    state : optional dict of per-bond float64 arrays (nb,).
    image : (nb,) int8 periodic image labels (`image_label`; default 0).
    """

    def __init__(self, offsets, partner, weight, status=None, slot=None, state=None,
                 image=None):
        self.offsets = np.ascontiguousarray(offsets, dtype=np.int64)
        self.partner = np.ascontiguousarray(partner, dtype=np.int64)
        self.weight = np.ascontiguousarray(weight, dtype=np.float64)
        nb = len(self.partner)
        self.status = (np.ones(nb, dtype=np.int8) if status is None
                       else np.ascontiguousarray(status, dtype=np.int8))
        self.slot = (np.full(nb, -1, dtype=np.int32) if slot is None
                     else np.ascontiguousarray(slot, dtype=np.int32))
        self.image = (np.zeros(nb, dtype=np.int8) if image is None
                      else np.ascontiguousarray(image, dtype=np.int8))
        self.state: dict[str, np.ndarray] = {
            k: np.ascontiguousarray(v, dtype=np.float64) for k, v in (state or {}).items()}
        if self.offsets[-1] != nb or len(self.weight) != nb or len(self.status) != nb \
                or len(self.image) != nb:
            raise ValueError("bond arrays disagree with offsets")

    # -- size ---------------------------------------------------------------------------------
    @classmethod
    def empty(cls, n: int = 0, state_names=()) -> "Bonds":
        return cls(np.zeros(n + 1, np.int64), np.empty(0, np.int64), np.empty(0),
                   state={k: np.empty(0) for k in state_names})

    @property
    def n(self) -> int:
        return len(self.offsets) - 1

    @property
    def n_bonds(self) -> int:
        return len(self.partner)

    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)

    def intact_counts(self) -> np.ndarray:
        """Active half-bonds per particle (the load-balance weight of a PD particle)."""
        return count_intact(self.offsets, self.status)

    def resident_bytes_per_bond(self) -> int:
        return (self.partner.itemsize + self.weight.itemsize + self.slot.itemsize
                + self.status.itemsize + self.image.itemsize
                + sum(a.itemsize for a in self.state.values()))

    def nbytes(self) -> int:
        return (self.offsets.nbytes + self.partner.nbytes + self.weight.nbytes
                + self.slot.nbytes + self.status.nbytes + self.image.nbytes
                + sum(a.nbytes for a in self.state.values()))

    def add_state(self, name: str, fill: float = 0.0) -> np.ndarray:
        """Declare a per-bond float64 state array (idempotent); returns it."""
        if name not in self.state:
            self.state[name] = np.full(self.n_bonds, fill, dtype=np.float64)
        return self.state[name]

    # -- segments: migration, checkpoints, reordering, SPB conversion --------------------------
    def _arrays(self) -> dict[str, np.ndarray]:
        out = {"partner": self.partner, "weight": self.weight, "status": self.status,
               "image": self.image, "slot": self.slot}
        out.update({"state." + k: v for k, v in self.state.items()})
        return out

    def extract(self, rows) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Copies of the segments of ``rows`` (integer indices), packed in that order:
        (counts (len(rows),) int64, {name: concatenated array}). Slots are not carried: they
        mean nothing on another rank or after a restart."""
        rows = np.asarray(rows, dtype=np.int64)
        index = segment_index(self.offsets, rows)
        counts = self.offsets[rows + 1] - self.offsets[rows]
        arrays = {k: v[index] for k, v in self._arrays().items() if k != "slot"}
        return counts, arrays

    def permute(self, order) -> None:
        """Reorder (and possibly shrink to) ``order``: new row ``i`` is old row ``order[i]``,
        following `ParticleSet.permute`."""
        order = np.asarray(order, dtype=np.int64)
        index = segment_index(self.offsets, order)
        counts = self.offsets[order + 1] - self.offsets[order]
        self.offsets = _offsets(counts)
        for name, arr in self._arrays().items():
            self._set(name, arr[index])

    def keep(self, mask_or_index) -> None:
        index = np.asarray(mask_or_index)
        if index.dtype == bool:
            index = np.flatnonzero(index)
        self.permute(index)

    def append(self, counts, arrays: dict[str, np.ndarray]) -> None:
        """Append segments for new rows (arrivals by migration, particles read from a
        checkpoint, MPM particles converted to PD): ``counts`` per new row and the
        concatenated arrays as `extract` returns them. State arrays absent from ``arrays``
        start at 0; slots start unresolved."""
        counts = np.asarray(counts, dtype=np.int64)
        m = int(counts.sum())
        for name in CORE_BOND_FIELDS:
            if len(arrays[name]) != m:
                raise ValueError(f"{name}: {len(arrays[name])} entries for {m} bonds")
        self.offsets = np.concatenate([self.offsets, self.offsets[-1] + np.cumsum(counts)])
        for name, arr in self._arrays().items():
            new = arrays.get(name)
            if new is None:
                new = np.full(m, -1 if name == "slot" else 0, dtype=arr.dtype)
            self._set(name, np.concatenate([arr, np.asarray(new, dtype=arr.dtype)]))

    def merge(self, rows, partner, weight, status=None) -> None:
        """Add half-bonds to existing rows (a particle converted to PD next to existing PD
        particles gives them new partners, issue 11): ``rows[k]`` gains the half-bond
        ``partner[k]`` with ``weight[k]``; every segment stays ordered by partner id. State
        arrays start at 0 and slots unresolved for the new half-bonds."""
        rows = np.asarray(rows, dtype=np.int64)
        partner = np.asarray(partner, dtype=np.int64)
        m = len(rows)
        if m == 0:
            return
        status = np.ones(m, np.int8) if status is None else np.asarray(status, np.int8)
        new = {"partner": partner, "weight": np.asarray(weight, np.float64), "status": status,
               "image": np.zeros(m, np.int8), "slot": np.full(m, -1, np.int32)}
        new.update({"state." + k: np.zeros(m) for k in self.state})
        # The segments are ordered already: sort the new half-bonds alone and merge them in,
        # O(bonds + m log m) where sorting everything cost a lexsort of all the bonds at each
        # SPB conversion (80-100 ms of a 270 ms step on watermelon_3d's 3000 PD particles).
        fresh = np.lexsort((partner, rows))
        order, counts = merged_order(self.offsets, self.partner, rows[fresh], partner[fresh],
                                     fresh)
        if len(order) == 0:
            raise ValueError("merge would duplicate a bond")
        for name, arr in self._arrays().items():
            self._set(name, np.concatenate([arr, new[name].astype(arr.dtype)])[order])
        self.offsets = _offsets(counts)

    def _set(self, name: str, arr: np.ndarray) -> None:
        if name.startswith("state."):
            self.state[name[6:]] = np.ascontiguousarray(arr)
        else:
            setattr(self, name, np.ascontiguousarray(arr))

    # -- halo ---------------------------------------------------------------------------------
    def resolve_slots(self, ids: np.ndarray, x0: np.ndarray, period=None) -> int:
        """Set each half-bond's local partner row from ``ids`` (global ids of the owned + halo
        points, owned rows first, any order) and their reference positions ``x0``. A periodic
        halo holds several copies (images) of one id: a half-bond takes the copy whose
        reference offset has its ``image`` label (``period``: (d,) lengths, 0 where an axis is
        not periodic); a partner bonded once whose label no copy has (bonds checkpointed
        before labels existed carry 0) takes the copy nearest in the reference configuration.
        Returns the number of intact half-bonds whose partner is absent (slot -1): the halo
        is too small, which the caller must treat as an error. Broken bonds may have absent
        partners."""
        ids = np.ascontiguousarray(ids, dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        dim = np.shape(x0)[1]
        period = (np.zeros(dim) if period is None
                  else np.ascontiguousarray(period, dtype=np.float64))
        return resolve_slots_kernel(self.offsets, self.partner, self.status, self.image,
                                    ids[order], order.astype(np.int64),
                                    np.ascontiguousarray(x0), period, self.slot)


def _offsets(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=out[1:])
    return out


@njit(cache=True, error_model="numpy")
def segment_index(offsets, rows):
    """Half-bond indices of the segments of ``rows``, concatenated in that order."""
    total = 0
    for r in rows:
        total += offsets[r + 1] - offsets[r]
    out = np.empty(total, dtype=np.int64)
    k = 0
    for r in rows:
        for b in range(offsets[r], offsets[r + 1]):
            out[k] = b
            k += 1
    return out


@njit(cache=True, error_model="numpy")
def merged_order(offsets, partner, rows, new_partner, new_index):
    """The order of the half-bonds of segments ``offsets``/``partner`` (each ordered by
    partner) with new half-bonds (``rows``, ``new_partner``, sorted by row then partner; new
    half-bond k is entry len(partner) + new_index[k] of the concatenation) merged in, every
    segment ordered by partner; and the new counts per row. An empty order when a new
    half-bond repeats an existing one or another new one."""
    n = len(offsets) - 1
    n_old = len(partner)
    m = len(rows)
    order = np.empty(n_old + m, dtype=np.int64)
    counts = np.empty(n, dtype=np.int64)
    pos = 0
    k = 0
    for p in range(n):
        i = offsets[p]
        end = offsets[p + 1]
        start = pos
        while True:
            fresh = k < m and rows[k] == p
            if fresh and k + 1 < m and rows[k + 1] == p and new_partner[k + 1] == new_partner[k]:
                return np.empty(0, dtype=np.int64), counts
            if i < end and (not fresh or partner[i] < new_partner[k]):
                order[pos] = i
                i += 1
            elif fresh:
                if i < end and partner[i] == new_partner[k]:
                    return np.empty(0, dtype=np.int64), counts
                order[pos] = n_old + new_index[k]
                k += 1
            else:
                break
            pos += 1
        counts[p] = pos - start
    return order, counts


@njit(cache=True, error_model="numpy")
def count_intact(offsets, status):
    n = len(offsets) - 1
    out = np.zeros(n, dtype=np.int64)
    for i in range(n):
        c = 0
        for b in range(offsets[i], offsets[i + 1]):
            c += status[b]
        out[i] = c
    return out


@njit(cache=True, error_model="numpy")
def resolve_slots_kernel(offsets, partner, status, image, sorted_ids, order, x0, period, slot):
    """Binary search of each partner id in ``sorted_ids``; among equal ids (periodic images)
    the copy with the half-bond's image label, or for a partner bonded once without such a
    copy the nearest to the bond's owner in ``x0``; writes ``slot``; returns the number of
    intact half-bonds whose partner is missing."""
    missing = 0
    m = len(sorted_ids)
    dim = x0.shape[1]
    X = np.empty(dim)
    periodic = False
    for a in range(dim):
        periodic = periodic or period[a] > 0.0
    for i in range(len(offsets) - 1):
        for b in range(offsets[i], offsets[i + 1]):
            pid = partner[b]
            lo, hi = 0, m
            while lo < hi:
                mid = (lo + hi) >> 1
                if sorted_ids[mid] < pid:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < m and sorted_ids[lo] == pid:
                best = order[lo]
                copies = lo + 1 < m and sorted_ids[lo + 1] == pid
                once = (b == offsets[i] or partner[b - 1] != pid) and \
                    (b + 1 == offsets[i + 1] or partner[b + 1] != pid)
                # A partner bonded more than once needs its labelled copy even when the
                # halo holds one copy only (the other image's bond broke and left it).
                if copies or (periodic and not once):
                    best = -1
                    if periodic:
                        k = lo
                        while k < m and sorted_ids[k] == pid:
                            j = order[k]
                            for a in range(dim):
                                X[a] = x0[j, a] - x0[i, a]
                            if image_label(X, period) == image[b]:
                                best = j
                                break
                            k += 1
                    if best < 0 and once:
                        best_d2 = np.inf
                        k = lo
                        while k < m and sorted_ids[k] == pid:
                            j = order[k]
                            d2 = 0.0
                            for a in range(dim):
                                t = x0[j, a] - x0[i, a]
                                d2 += t * t
                            if d2 < best_d2:
                                best_d2 = d2
                                best = j
                            k += 1
                slot[b] = best
                if best < 0 and status[b] != 0:
                    missing += 1
            else:
                slot[b] = -1
                if status[b] != 0:
                    missing += 1
    return missing

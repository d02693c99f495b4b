"""PD bond segments cross ranks whole: partner ids, weights, status and every per-bond state
array (a plastic stretch, a viscous force) arrive with their particle, row by row.

`hpcmpm.parallel.pd_halo.send_segments` carries the segments for both migration entry points:
`redistribute_segments` (the PD extensions' route after the engine's migration, rebalancing
or a restart) and `migrate_with_bonds` (the off-grid PD solver, pd/distributed.py). The scene
tests on 2 ranks happen not to depend on a bond's state across a move, so these tests check
the segments directly: every half-bond's values are a function of (owner id, partner id)
here, so each received bond can be checked exactly, whichever rank it came from."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from hpcmpm.parallel.pd_halo import migrate_with_bonds, redistribute_segments
from hpcmpm.pd.bonds import Bonds
from mpi_helpers import cloud, particle_set, strided_share

N = 400
STATE_NAMES = ("plastic_stretch", "viscous_force")


def partners_of(index: int, ids: np.ndarray) -> np.ndarray:
    """Partner ids of particle ``ids[index]``: 0 to 5 of them (an empty segment too),
    ascending, as `Bonds` keeps each segment."""
    n = len(ids)
    others = {(index + 3 * k + 1) % n for k in range(index % 6)} - {index}
    return np.sort(ids[list(others)])


def bond_values(owner: np.ndarray, partner: np.ndarray) -> dict[str, np.ndarray]:
    """Every per-bond array as a function of (owner id, partner id). The states are never 0
    (a state dropped in transit starts at 0 on arrival, `Bonds.append`), and swapping the
    ends changes them, so a bond filed under the wrong owner fails too."""
    o, q = owner.astype(np.float64), partner.astype(np.float64)
    return {"weight": 1.0 + np.sin(o) + 1e-3 * q,
            "status": ((owner + 2 * partner) % 3 != 0).astype(np.int8),
            "state.plastic_stretch": 0.5 + 1e-3 * o + 1e-6 * q * q,
            "state.viscous_force": -2.0 - np.cos(o * q)}


def make_bonds(row_ids: np.ndarray, all_ids: np.ndarray) -> Bonds:
    """The bond segments of the particles ``row_ids`` (in that row order)."""
    index = np.searchsorted(all_ids, row_ids)
    parts = [partners_of(int(i), all_ids) for i in index]
    counts = np.array([len(p) for p in parts], dtype=np.int64)
    partner = np.concatenate(parts) if parts else np.empty(0, np.int64)
    values = bond_values(np.repeat(row_ids, counts), partner)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    return Bonds(offsets, partner, values["weight"], values["status"],
                 state={k[6:]: values[k] for k in values if k.startswith("state.")})


def check_rows(bonds: Bonds, row_ids: np.ndarray, all_ids: np.ndarray) -> None:
    """``bonds`` row r holds exactly the segment of particle ``row_ids[r]``, every array
    bit for bit (the values only travel: nothing may round them)."""
    assert bonds.n == len(row_ids)
    assert sorted(bonds.state) == sorted(STATE_NAMES)
    want = make_bonds(row_ids, all_ids)
    np.testing.assert_array_equal(bonds.offsets, want.offsets)
    np.testing.assert_array_equal(bonds.partner, want.partner)
    np.testing.assert_array_equal(bonds.weight, want.weight)
    np.testing.assert_array_equal(bonds.status, want.status)
    for name in STATE_NAMES:
        np.testing.assert_array_equal(bonds.state[name], want.state[name], err_msg=name)
    # Slots mean nothing after a move: the halo rebuild resolves them again.
    assert np.all(bonds.slot == -1)


@pytest.mark.parallel(ranks=[2])
def test_redistribute_segments_carries_every_bond_array():
    domain = Domain(2, 1.0 / 16, np.zeros(2), np.ones(2))
    all_ids = np.arange(N, dtype=np.int64) * 7 + 3
    # Before: a strided share. After: a contiguous half each, in descending id order, so
    # half of each rank's rows leave, the rest stay and all are reordered.
    before = all_ids[np.arange(N) % domain.size == domain.rank]
    after = np.array_split(all_ids, domain.size)[domain.rank][::-1].copy()
    bonds = make_bonds(before, all_ids)
    check_rows(bonds, before, all_ids)

    got = redistribute_segments(domain, bonds, before, after)

    np.testing.assert_array_equal(got, after)
    arrived = np.setdiff1d(after, before)
    assert len(arrived) == N // (2 * domain.size)       # 100 particles changed rank here
    check_rows(bonds, after, all_ids)
    # The arrivals carry bonds of their own (300 half-bonds on rank 0, 200 on rank 1), so the
    # checks above covered sent values, not only the rows that stayed.
    rows = np.flatnonzero(np.isin(after, arrived))
    assert bonds.counts()[rows].sum() >= 200
    assert domain.sum(bonds.n_bonds) == sum(len(partners_of(i, all_ids)) for i in range(N))


@pytest.mark.parallel(ranks=[2])
def test_migrate_with_bonds_carries_every_bond_array():
    domain = Domain(2, 1.0 / 16, np.zeros(2), np.ones(2))
    values = cloud(2, N, seed=5)
    all_ids = values["id"]
    # A strided share: about half of each rank's particles lie in the other rank's box.
    p = particle_set(2, values, strided_share(values, domain))
    before = p["id"].copy()
    bonds = make_bonds(before, all_ids)

    moved = migrate_with_bonds(domain, p, bonds)

    assert moved > N // 4                           # measured: 200 of 400
    assert np.all(domain.owners(p["x"]) == domain.rank)
    check_rows(bonds, p["id"], all_ids)
    arrived = ~np.isin(p["id"], before)
    assert bonds.counts()[arrived].sum() >= 100      # measured: 309 and 198 half-bonds
    assert domain.sum(p.n) == N
    assert domain.sum(bonds.n_bonds) == sum(len(partners_of(i, all_ids)) for i in range(N))

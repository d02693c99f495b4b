"""The off-grid PD solver on 2 ranks (hpcmpm/pd/distributed.py) where test_pd_ranks.py does not
look: the state halo of LPS theta (test_pd_ranks' LPS(1.0, 0.5) is the 2D case mu = kappa/2,
in which theta drops out of the bond force up to round-off), the halo reach that keeps stretched bonds
across the ranks' cut, the max_bond_stretch cap, and the collective time step. Each is
checked bitwise against the serial integrator (pd/integrator.py)."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from hpcmpm.pd.distributed import DistributedPDBody
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS
from hpcmpm.pd.moduli import stable_time_step
from hpcmpm.pd.pmb import PMB
from hpcmpm.state import SCALAR, VECTOR, FieldSpec, ParticleSet

DELTA = 3.015


def plate(v_of):
    """A 20 x 14 plate (spacing 1), ids not in row order, velocities ``v_of(x0)``."""
    g = np.stack(np.meshgrid(np.arange(20.0), np.arange(14.0), indexing="ij"), -1)
    x0 = g.reshape(-1, 2) + 0.5
    ids = np.random.default_rng(5).permutation(len(x0)).astype(np.int64) * 3 + 1
    return x0, ids, v_of(x0)


def distributed(x0, ids, v, model, mass=None, **kw):
    domain = Domain(2, 1.0, [-40.0, -40.0], [60.0, 54.0])
    specs = {"x0": FieldSpec(VECTOR), "pd_m": FieldSpec(SCALAR),
             "pd_wvol0": FieldSpec(SCALAR), "damage": FieldSpec(SCALAR)}
    p = ParticleSet(2, specs)
    mine = np.flatnonzero(np.arange(len(ids)) % domain.size == domain.rank)
    mass = np.ones(len(ids)) if mass is None else mass
    p.append({"id": ids[mine], "x": x0[mine], "x0": x0[mine], "v": v[mine],
              "mass": mass[mine], "vol0": np.ones(len(mine))})
    domain.decompose(p)
    return domain, p, DistributedPDBody(domain, p, model, 1.0, DELTA, **kw)


def by_id(domain, p, body):
    parts = domain.allgather((p["id"].copy(), p["x"].copy(), p["v"].copy(),
                              int((body.bonds.status == 0).sum())))
    got = np.concatenate([a[0] for a in parts])
    order = np.argsort(got)
    return (got[order], np.concatenate([a[1] for a in parts])[order],
            np.concatenate([a[2] for a in parts])[order], sum(a[3] for a in parts))


def compare(serial, ids, domain, p, body):
    got_ids, x, v, broken = by_id(domain, p, body)
    ref = np.argsort(ids)
    assert np.array_equal(got_ids, ids[ref])
    assert np.array_equal(x, serial.x[ref])
    assert np.array_equal(v, serial.v[ref])
    assert broken == int((serial.pts.bonds.status == 0).sum())
    return broken


@pytest.mark.parallel(ranks=[2])
def test_lps_theta_crosses_the_ranks_cut():
    """LPS with mu != kappa/2 (theta enters the force): bitwise the serial run, which a
    halo that refreshes the state fields but theta misses."""
    x0, ids, v = plate(lambda x: 0.03 * np.stack([np.sin(x[:, 0] / 3.0),
                                                  np.cos(x[:, 1] / 2.0)], axis=1))
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    serial = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, LPS(1.0, 0.3), velocity=v)
    domain, p, body = distributed(x0, ids, v, LPS(1.0, 0.3))
    for _ in range(20):
        serial.step(0.4)
        body.step(0.4)
    compare(serial, ids, domain, p, body)
    assert domain.size == 1 or body.halo.n_halo > 0


@pytest.mark.parallel(ranks=[2])
def test_stretched_bonds_keep_their_partners_across_the_cut():
    """A plate stretched homogeneously from its left edge by about 58 % with a critical
    stretch of 0.8: no bond breaks, so partners beyond the family radius (up to radius x
    1.58) must reach their owners through the halo (reach = radius (1 + s0), plus the
    skin). The plate streams through the ranks' cut at x = 10; measured: intact partners
    lie up to 4.59 beyond their owner's box, past radius + skin = 4.015 (a halo reach
    without the stretch allowance drops them). Bitwise the serial run."""
    center = np.array([0.0, 7.0])
    x0, ids, v = plate(lambda x: 0.02 * (x - center))
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    serial = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, PMB(1e-3, 0.8), velocity=v)
    domain, p, body = distributed(x0, ids, v, PMB(1e-3, 0.8))
    for _ in range(30):
        serial.step(1.0)
        body.step(1.0)
    stretch = np.abs(serial.x - center).max() / np.abs(x0 - center).max() - 1.0
    assert stretch > 0.5                 # measured 0.576
    assert compare(serial, ids, domain, p, body) == 0


@pytest.mark.parallel(ranks=[2])
def test_max_bond_stretch_caps_the_critical_stretch():
    """max_bond_stretch = 0.02 breaks the bonds of a PMB with critical stretch 0.5 as the
    serial PMB with critical stretch 0.02 does (the halves of the plate pulled apart)."""
    x0, ids, v = plate(lambda x: np.where(x[:, :1] > 10, 0.04, -0.04) * np.array([1.0, 0.3]))
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    serial = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, PMB(1.0, 0.02), velocity=v)
    domain, p, body = distributed(x0, ids, v, PMB(1.0, 0.5), max_bond_stretch=0.02)
    for _ in range(60):
        serial.step(0.4)
        body.step(0.4)
    assert compare(serial, ids, domain, p, body) > 100      # measured 654 half-bonds


@pytest.mark.parallel(ranks=[2])
def test_stable_dt_is_the_rule_over_all_ranks():
    """DistributedPDBody.stable_dt() is 0.8 min_p sqrt(2 rho_p / sum_q V_q c w / |X|) over
    every rank's particles, bitwise the serial `stable_time_step`. The density varies with
    the id so each rank's own minimum differs from the global one."""
    x0, ids, v = plate(lambda x: np.zeros_like(x))
    rho = 1.0 + 1e-3 * ids
    model = PMB(1.0, 0.5)
    domain, p, body = distributed(x0, ids, v, model, mass=rho)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    want = stable_time_step(x0, np.ones(len(x0)), rho, fam.bonds, 1.0, len(x0), 0.8)
    got = body.stable_dt()
    assert got == want
    assert 0.8 * body.stable_dt(safety=1.0) == want
    # Each rank's own minimum alone would be another step on one of the ranks.
    local = stable_time_step(body.pts.x0, body.pts.vol, np.concatenate(
        [p["mass"], np.zeros(len(body.pts.x) - p.n)]), body.bonds, 1.0, p.n, 0.8)
    assert domain.size == 1 or not all(domain.allgather(local == want))


@pytest.mark.parallel(ranks=[2])
def test_route_half_bonds_sends_each_row_to_its_owners_rank():
    """A restart's half-bond rows (an even slice of the file per rank) reach the rank holding
    their owner, with every value: here each rank holds every other id, so a rank's ids are
    no contiguous range of the sorted ids (in the scene restarts they happen to be)."""
    from hpcmpm.parallel.pd_halo import route_half_bonds

    domain = Domain(2, 1.0 / 16, np.zeros(2), np.ones(2))
    all_ids = np.arange(300, dtype=np.int64) * 7 + 3
    mine = np.random.default_rng(domain.rank).permutation(all_ids[domain.rank::domain.size])
    owner = np.repeat(all_ids, all_ids % 4)              # 0 to 3 half-bonds per particle
    partner = owner[::-1].copy()
    rows = np.array_split(np.arange(len(owner)), domain.size)[domain.rank]
    value = lambda o, q: np.sin(o.astype(np.float64)) + 1e-3 * q  # noqa: E731
    arrays = {"owner": owner[rows], "partner": partner[rows],
              "state.s": value(owner[rows], partner[rows])}
    got = route_half_bonds(domain, arrays, mine)
    assert np.all(np.isin(got["owner"], mine))
    want = np.flatnonzero(np.isin(owner, mine))
    order = np.lexsort((got["partner"], got["owner"]))
    ref = want[np.lexsort((partner[want], owner[want]))]
    np.testing.assert_array_equal(got["owner"][order], owner[ref])
    np.testing.assert_array_equal(got["partner"][order], partner[ref])
    np.testing.assert_array_equal(got["state.s"][order], value(owner[ref], partner[ref]))

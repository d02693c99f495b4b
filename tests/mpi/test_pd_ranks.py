"""PD bodies on 1, 2 and 4 ranks: bitwise the serial integrator's positions and velocities by
id, and the same broken-bond set, while a plate tears apart and its pieces cross ranks."""

import numpy as np
import pytest

from hpcmpm.materials.linear_elastic import _stress_2d
from hpcmpm.parallel import Domain
from hpcmpm.pd.correspondence import Correspondence
from hpcmpm.pd.distributed import DistributedPDBody
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS
from hpcmpm.pd.pmb import PMB
from hpcmpm.state import SCALAR, VECTOR, FieldSpec, ParticleSet

DELTA, S0 = 3.015, 0.02
CRACK = np.array([[[9.5, -1.0], [9.5, 5.0]]])   # a notch from the bottom edge at x = 9.5


def make_model(name):
    if name == "pmb":
        return PMB(1.0, S0)
    if name == "lps":
        return LPS(1.0, 0.5, S0)
    return Correspondence(2, lambda F, tau: _stress_2d(np.ascontiguousarray(F), tau, 0.5, 0.3),
                          0.1, S0)


def plate():
    """A 20 x 14 plate, ids not in row order."""
    g = np.stack(np.meshgrid(np.arange(20.0), np.arange(14.0), indexing="ij"), -1)
    x0 = g.reshape(-1, 2) + 0.5
    rng = np.random.default_rng(5)
    ids = rng.permutation(len(x0)).astype(np.int64) * 3 + 1
    # Halves pulled apart, a drift that carries particles across rank boundaries, noise.
    v = np.where(x0[:, :1] > 10, 0.04, -0.04) * np.array([1.0, 0.3]) + 0.06 \
        + 0.005 * rng.standard_normal(x0.shape)
    return x0, ids, v


def broken_pairs(ids_rows, bonds):
    owner = np.repeat(ids_rows, bonds.counts())
    gone = bonds.status == 0
    return set(zip(owner[gone].tolist(), bonds.partner[gone].tolist()))


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_pd_bodies_are_rank_independent():
    for name in ("pmb", "lps", "correspondence"):     # one launch per rank count
        check_model(name)


def check_model(name):
    x0, ids, v = plate()
    steps, dt = 120, 0.4
    # Serial reference (every rank computes it: small).
    fam = find_families(x0, ids, len(x0), 1.0, DELTA, precracks=CRACK)
    serial = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, make_model(name), velocity=v)
    for _ in range(steps):
        serial.step(dt)

    domain = Domain(2, 1.0, [-20.0, -20.0], [40.0, 34.0])
    specs = {"x0": FieldSpec(VECTOR), "pd_m": FieldSpec(SCALAR),
             "pd_wvol0": FieldSpec(SCALAR), "damage": FieldSpec(SCALAR)}
    p = ParticleSet(2, specs)
    mine = np.flatnonzero(np.arange(len(ids)) % domain.size == domain.rank)
    p.append({"id": ids[mine], "x": x0[mine], "x0": x0[mine], "v": v[mine],
              "mass": np.ones(len(mine)), "vol0": np.ones(len(mine))})
    domain.decompose(p)
    body = DistributedPDBody(domain, p, make_model(name), 1.0, DELTA, precracks=CRACK)
    for _ in range(steps):
        body.step(dt)

    parts = domain.allgather((p["id"].copy(), p["x"].copy(), p["v"].copy(),
                              broken_pairs(p["id"], body.bonds), p["damage"].copy()))
    got_ids = np.concatenate([a[0] for a in parts])
    order = np.argsort(got_ids)
    ref = np.argsort(ids)
    assert np.array_equal(got_ids[order], ids[ref])
    # Bitwise: the same sums in the same order from bitwise equal inputs.
    assert np.array_equal(np.concatenate([a[1] for a in parts])[order], serial.x[ref])
    assert np.array_equal(np.concatenate([a[2] for a in parts])[order], serial.v[ref])
    assert np.array_equal(np.concatenate([a[4] for a in parts])[order], serial.damage()[ref])
    broken = set().union(*[a[3] for a in parts])
    want = broken_pairs(ids, serial.pts.bonds)
    assert broken == want
    assert len(want) > 100                      # the plate did tear
    # Particles crossed ranks, and the plan was reused between rebuilds.
    assert body.migrated > 0 or domain.size == 1
    assert body.halo.builds < steps / 2

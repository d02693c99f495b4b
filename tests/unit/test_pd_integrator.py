"""The serial PD integrator's periodic images (hpcmpm/pd/integrator.py) and the PD time-step
rule's safety factor (hpcmpm/pd/moduli.py).

Images: `PDBody.compute_forces` refreshes the model's state fields (``halo_fields``: LPS
theta, correspondence A/F/active) on the image rows of a periodic box from their sources
before the bond forces read them. A body whose state varies along the periodic axis shows a
skipped refresh: the image rows keep their stale values, and the forces near the periodic
faces are no longer those of the same body repeated over three periods.

Time step: the issue's rule dt = 0.8 min_p sqrt(2 rho / sum_q V_q c w / |X|). The default
0.8 of `moduli.stable_time_step` is used by no caller in hpcmpm (PDBody.stable_dt and
DistributedPDBody.stable_dt pass their own default 0.8; a scene's step comes from
`PeridynamicMaterial.dt_limit` over a full lattice family); the tests pin each default and
check that a scene's step is the rule over the bonds the scene actually made."""

import math

import numpy as np
import pytest

from hpcmpm.materials.linear_elastic import _stress_2d
from hpcmpm.pd.correspondence import Correspondence
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS
from hpcmpm.pd.moduli import silling_askari_steps, stable_time_step
from hpcmpm.pd.pmb import PMB

DELTA = 3.015
NX, NY = 12, 8          # a 12 x 8 lattice, periodic along x (period 12)


def make_model(name):
    if name == "lps":
        return LPS(1.0, 0.3)    # not mu = kappa/2: there theta drops out of 2D LPS forces
    return Correspondence(2, lambda F, tau: _stress_2d(np.ascontiguousarray(F), tau, 0.5, 0.3),
                          0.1)


def lattice(copies: int):
    """``copies`` periods of the 12 x 8 lattice side by side (x in [0, 12 copies)), spacing 1,
    and a displacement periodic in x (period 12) that varies the state along the axis."""
    g = np.stack(np.meshgrid(np.arange(NX * copies, dtype=np.float64),
                             np.arange(NY, dtype=np.float64), indexing="ij"), -1)
    x0 = g.reshape(-1, 2) + 0.5
    phase = 2.0 * math.pi * x0[:, 0] / NX
    u = np.stack([0.03 * np.sin(phase), 0.02 * np.cos(phase) * x0[:, 1] / NY], axis=1)
    return x0, u


@pytest.mark.parametrize("name", ["lps", "correspondence"])
def test_periodic_images_carry_the_state_the_forces_read(name):
    # The periodic body: one period, images appended by find_families.
    x0, u = lattice(1)
    ids = np.arange(len(x0), dtype=np.int64)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA, period=[float(NX), 0.0])
    model = make_model(name)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, model)
    n = len(x0)
    assert len(body.src) > 0
    body.pts.x[:n] = x0 + u
    body.compute_forces()
    # Every state field's image rows are their sources' values, bit for bit.
    for field in model.halo_fields:
        arr = getattr(model, field)
        assert np.array_equal(arr[n:], arr[body.src]), field
    assert np.abs(model.theta if name == "lps" else model.F[:, 0, 0] - 1.0).max() > 1e-3

    # The same body repeated over three periods (no images): its middle copy's forces are
    # the periodic body's. Only the summation order differs (partners sorted by id: the
    # images carry their sources' ids, the copies their own); measured max |diff| / max |f|:
    # 6.0e-14 (lps) and 1.8e-13 (correspondence); with the images' state left stale, 0.12 and
    # 0.51.
    x3, u3 = lattice(3)
    ids3 = np.arange(len(x3), dtype=np.int64)
    fam3 = find_families(x3, ids3, len(x3), 1.0, DELTA)
    wide = PDBody(x3, np.ones(len(x3)), ids3, 1.0, fam3, make_model(name))
    wide.pts.x[: len(x3)] = x3 + u3
    wide.compute_forces()
    middle = (x3[:, 0] >= NX) & (x3[:, 0] < 2 * NX)
    ref = wide.force[middle]
    assert np.array_equal(x3[middle] - [NX, 0.0], x0)    # the same row order
    err = np.abs(body.force - ref).max() / np.abs(ref).max()
    assert err < 1e-12, f"{err:.2e}"


def test_periodic_lps_body_keeps_its_image_state_over_steps():
    """A few steps of the periodic body against the three-period body: the displacements of
    the middle copy agree to round-off (measured 3.1e-13 of the largest after 3 steps; a
    skipped image refresh of theta makes it 2.6e-3)."""
    x0, u = lattice(1)
    ids = np.arange(len(x0), dtype=np.int64)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA, period=[float(NX), 0.0])
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, LPS(1.0, 0.3), velocity=u)
    x3, u3 = lattice(3)
    ids3 = np.arange(len(x3), dtype=np.int64)
    wide = PDBody(x3, np.ones(len(x3)), ids3, 1.0, find_families(x3, ids3, len(x3), 1.0, DELTA),
                  LPS(1.0, 0.3), velocity=u3)
    middle = (x3[:, 0] >= NX) & (x3[:, 0] < 2 * NX)
    # The wide body's free ends reach its middle copy within a few steps (influence spreads
    # two horizons a step with LPS; measured 4e-10 at step 4): 3 steps.
    for _ in range(3):
        body.step(0.2)
        wide.step(0.2)
    got, ref = body.x - x0, wide.x[middle] - x3[middle]
    err = np.abs(got - ref).max() / np.abs(ref).max()
    assert err < 1e-11, f"{err:.2e}"


def bonds_and_rule(safety):
    """A 10 x 10 PMB plate's bonds and the issue's rule over them, written out."""
    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0), indexing="ij"), -1)
    x0 = g.reshape(-1, 2) + 0.5
    ids = np.arange(len(x0), dtype=np.int64)
    vol = np.full(len(x0), 0.9)
    rho = 2.5
    c = 3.0
    b = find_families(x0, ids, len(x0), 1.0, DELTA).bonds
    best = math.inf
    for p in range(len(x0)):
        k = 0.0
        for j in range(b.offsets[p], b.offsets[p + 1]):
            q = b.slot[j]
            k += vol[q] * c * b.weight[j] / math.dist(x0[q], x0[p])
        best = min(best, math.sqrt(2 * rho / k))
    return x0, ids, vol, rho, c, b, safety * best


def test_stable_time_step_default_safety_is_0_8():
    x0, ids, vol, rho, c, b, want = bonds_and_rule(0.8)
    got = stable_time_step(x0, vol, rho, b, c, len(x0))
    assert got == pytest.approx(want, rel=1e-13)
    out = np.empty(len(x0))
    raw = silling_askari_steps(x0, vol, np.full(len(x0), rho), b.offsets, b.slot, b.status,
                               b.weight, c, len(x0), out)
    assert got == 0.8 * raw


def test_pd_body_stable_dt_default_safety_is_0_8():
    x0, ids, vol, rho, c, _, want = bonds_and_rule(0.8)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    model = PMB(c, math.inf)
    model.time_step_micromodulus = lambda: c
    body = PDBody(x0, vol, ids, rho, fam, model)
    assert body.stable_dt() == pytest.approx(want, rel=1e-13)
    assert body.stable_dt() == 0.8 * body.stable_dt(safety=1.0)


def test_a_pd_scene_step_is_the_rule_over_its_bonds():
    """A PD scene's step (`Simulation.stable_dt` of an off-grid PMB plate) is
    0.8 min_p sqrt(2 rho / sum_q V_q c w / |X|) over the bonds the scene made: the min is
    at an interior particle, whose family is the full lattice family `dt_limit` sums."""
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.scene import load_scene
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/pd_plate_tear_2d.toml")
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    dt = sim.stable_dt()
    sim.step(dt)
    ext = sim.extensions[0]
    glass = ext.material
    start, stop = sim.group_slices[ext.group]
    p = sim.particles
    rho = p["mass"][start:stop] / p["vol0"][start:stop]
    b, pts = ext.bonds, ext.pts
    rho_all = np.concatenate([rho, np.zeros(len(pts.x) - (stop - start))])
    want = stable_time_step(pts.x0, pts.vol, rho_all, b, glass.time_step_micromodulus(),
                            stop - start, 0.8)
    assert rho == pytest.approx(glass.density, rel=1e-14)
    assert dt == pytest.approx(want, rel=1e-12)
    assert sim.stable_dt() == dt

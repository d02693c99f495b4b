"""Load-balance weights: the bisection cuts at the weighted quantile (and uniform weights cut
as the count does), a PD particle weighs 1 + c_b x (active half-bonds) MPM particles, an SPB
particle once it is PD (its own count too), a scene without PD has no weights, and the c_b
measurement script runs."""

import runpy
import sys

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.parallel.decomposition import recursive_bisection
from hpcmpm.pd.load import bond_cost
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.simulation import Simulation


def test_bisection_cuts_at_the_weighted_median():
    """100 particles in each of cells 0..9 along x; the first five cells weigh 3 each: the
    weighted half (2000 of 4000) lies below x-cell 3 + 1/3, so the cut is at cell 3 (a
    cut at the count median, cell 5, would leave 1500 against 500)."""
    cells = np.repeat(np.arange(10), 100)[:, None] * np.array([[1, 0]])
    weights = np.where(cells[:, 0] < 5, 3, 1).astype(np.int64)
    same = lambda a: a  # noqa: E731  (one rank: the reductions are the identity)
    by_count = recursive_bisection(cells, 2, np.array([10, 1]), same, same)
    by_weight = recursive_bisection(cells, 2, np.array([10, 1]), same, same, weights=weights)
    assert by_count[0, 1, 0] == 5 and by_weight[0, 1, 0] == 3


def test_uniform_weights_cut_as_the_count_does():
    """An SPB scene before any conversion weighs every particle 64 units: the boxes must be
    those of the count, bitwise (64 = 2^6 scales the histograms and the float quantile target
    exactly), on a random cloud over 8 boxes (three levels of cuts)."""
    rng = np.random.default_rng(3)
    cells = np.floor(rng.normal(20.0, 6.0, size=(5000, 3))).astype(np.int64).clip(0, 39)
    same = lambda a: a  # noqa: E731
    n_cells = np.array([40, 40, 40])
    by_count = recursive_bisection(cells, 8, n_cells, same, same)
    by_weight = recursive_bisection(cells, 8, n_cells, same, same,
                                    weights=np.full(len(cells), 64, np.int64))
    assert np.array_equal(by_count, by_weight)


def test_pd_particles_weigh_their_active_bonds():
    """Before the bonds exist, an interior family (36 half-bonds at 3.015 spacings in 2D);
    afterwards each particle's own active count, lowered when bonds break."""
    sim = Simulation(load_scene("inputs/pd_plate_tear_2d.toml"), None)
    sim.domain = make_domain(sim.scene)
    initial_particles(sim)
    unit, c_b = sim.particle_weight, bond_cost(2, "pmb")
    assert np.all(sim.load_weights() == unit + round(unit * c_b * 36))
    sim.ensure_grouped()
    ext = sim.extensions[0]
    ext.prepare()
    active = ext.bonds.intact_counts()
    assert active.min() < 36 == active.max()     # surface particles have fewer
    b = ext.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    wv = b.weight * ext.pts.vol[b.slot]
    initial = np.bincount(owner, wv, minlength=b.n)
    b.status[: b.offsets[5]] = 0  # the first five particles lose theirs
    b.status[np.random.default_rng(0).random(b.n_bonds) < 0.3] = 0   # and a third of all
    ext.broken += 1
    ext.write_damage(*sim.group_slices[0])
    active = b.intact_counts()
    assert np.all(active[:5] == 0)
    want = unit + np.rint(unit * c_b * active).astype(np.int64)
    assert np.array_equal(sim.load_weights(), want)
    # Damage phi = 1 - sum_intact w V / sum_initial w V (003 eq. 4.8): over the bonds the
    # particle started with, not over those left (which would make phi 0 everywhere).
    intact = np.bincount(owner, wv * (b.status != 0), minlength=b.n)
    start, stop = sim.group_slices[0]
    assert np.abs(sim.particles["damage"][start:stop] - (1 - intact / initial)).max() < 1e-14
    assert np.all(sim.particles["damage"][start:start + 5] == 1.0)


SPB_SCENE = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.05
transfer = "mls"
end_time = 0.01
[[materials]]
name = "m"
type = "fixed_corotated"
density = 1.0
E = 100.0
nu = 0.3
failure = { model = "spb", grid_energy = 1.0e6, bond_energy = 1.0 }
[[bodies]]
material = "m"
shape = "box"
lower = [0.3, 0.3]
upper = [0.7, 0.7]
"""


def hand_count(x0, spacing, horizon=3.015):
    """Half-bonds of each point by brute force over all pairs: partners with |X| < (horizon +
    1/2) spacings (PA-HHB partial volumes: every partner whose cell overlaps the horizon)."""
    d2 = np.sum((x0[:, None, :] - x0[None, :, :]) ** 2, axis=-1) / spacing ** 2
    return np.sum((d2 > 0) & (d2 < (horizon + 0.5) ** 2), axis=1)


def test_spb_particles_weigh_their_bonds_once_pd():
    """Before conversion every SPB particle weighs one unit; once PD (all of them, the
    verification switch), each weighs its own intact half-bonds at the correspondence
    model's c_b: the count of partners within the family radius, by brute force from the
    reference positions (an interior particle of the 2D lattice has 36 at the default 3.015
    spacings, |k|^2 < 3.515^2 by hand; a corner one 12 (|k|^2 < 3.515^2 over the quarter
    plane k >= 0 without the origin), not the interior family the weights once assumed).
    Breaking the half-bonds of three particles by hand, the next step's count drops them to
    one unit and leaves the others."""
    sc = parse_scene(SPB_SCENE, "spb.toml")
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    unit, c_b = sim.particle_weight, bond_cost(2, "correspondence")
    assert np.all(sim.load_weights() == unit)
    ext = sim.extensions[0]
    ext.convert_all = True
    sim.step(1e-4)
    p = sim.particles
    assert np.all(p["model"] == 1)
    want_bonds = hand_count(p["x0"], ext.spacing)
    assert want_bonds.max() == 36 and want_bonds.min() == 12
    assert np.array_equal(p["active_bonds"], want_bonds)
    want = unit + np.rint(unit * c_b * want_bonds).astype(np.int64)
    assert np.array_equal(sim.load_weights(), want)
    # Break every half-bond of three particles (bond rows of ids 0, 1, 2) and step again at
    # rest: nothing else breaks, and their partners keep their own half-bonds to them.
    b = ext.bonds
    for row in np.flatnonzero(np.isin(ext.bond_ids, [0, 1, 2])):
        b.status[b.offsets[row]:b.offsets[row + 1]] = 0
    sim.step(1e-4)
    cut = np.isin(p["id"], [0, 1, 2])
    want_bonds = np.where(cut, 0, hand_count(p["x0"], ext.spacing))
    assert np.array_equal(p["active_bonds"], want_bonds)
    want = unit + np.rint(unit * c_b * want_bonds).astype(np.int64)
    assert np.array_equal(sim.load_weights(), want) and np.all(sim.load_weights()[cut] == unit)


def test_scene_without_pd_has_no_weights():
    sim = Simulation(load_scene("inputs/disks_2d.toml"), None)
    assert sim.load_weights() is None


def test_bond_cost_script_smoke(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["measure_pd_bond_cost.py", "--cells", "4", "--steps",
                                      "2", "--repeats", "1"])
    runpy.run_path("scripts/measure_pd_bond_cost.py", run_name="__main__")
    assert "c_b = " in capsys.readouterr().out


@pytest.mark.parametrize("flag", [[], ["--unweighted"]])
def test_balance_bench_smoke(monkeypatch, capsys, flag):
    """scripts/bench_pd_balance.py on one rank, coarse and short (the study runs it on 2)."""
    monkeypatch.setattr(sys, "argv", ["bench_pd_balance.py", "--dx", "0.05", "--steps", "2",
                                      "--warmup", "2", *flag])
    runpy.run_path("scripts/bench_pd_balance.py", run_name="__main__")
    out = capsys.readouterr().out
    assert out.startswith("unweighted:" if flag else "weighted:") and "compute per rank" in out


@pytest.mark.parametrize("model", ["bond_energy", "unknown"])
def test_a_model_without_a_measured_cost_is_weighed_as_lps(model):
    assert bond_cost(3, model) == bond_cost(3, "lps")

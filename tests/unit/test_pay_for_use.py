"""A scene pays only for what it uses: fields, kernels and grid memory."""

from pathlib import Path

import numpy as np

from hpcmpm.materials import MATERIALS
from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene, parse_scene


def test_elastic_scene_has_no_plastic_fields_and_never_runs_the_snow_kernel(monkeypatch):
    calls = []
    snow = MATERIALS["snow"]
    original = snow.update_stress
    monkeypatch.setattr(snow, "update_stress",
                        lambda self, *a, **k: (calls.append(1), original(self, *a, **k))[1])
    sim = simulate(load_scene("inputs/disks_2d.toml", ["simulation.end_time=0.05"]))
    assert sim.step_index > 0
    assert calls == []
    names = set(sim.particles.field_names())
    assert not names & {"Fp", "Jp", "prescribed"}
    # MLS needs C; nothing else beyond the core fields.
    assert names == {"id", "group", "x", "v", "mass", "vol0", "F", "C"}
    assert "impulse" not in sim.grid.fields and "velocity_old" not in sim.grid.fields


def test_pic_has_no_affine_field_and_snow_declares_its_state():
    sim = simulate(load_scene("inputs/disks_2d.toml",
                              ["simulation.end_time=0.01", 'simulation.transfer="pic"']))
    assert "C" not in sim.particles
    snow = simulate(load_scene("inputs/snow_block_3d.toml",
                               ["simulation.end_time=0.002", "simulation.dx=0.05"]))
    assert {"Fp", "Jp"} <= set(snow.particles.field_names())


def test_empty_space_costs_no_grid_memory():
    """The same cube in a domain 8x larger per axis gets the same grid block."""
    small = load_scene("inputs/jelly_cube_3d.toml",
                       ["simulation.end_time=0.004", "simulation.dx=0.05"])
    big = load_scene("inputs/jelly_cube_3d.toml",
                     ["simulation.end_time=0.004", "simulation.dx=0.05",
                      "simulation.domain.upper=[8.0, 8.0, 8.0]"])
    a, b = simulate(small), simulate(big)
    assert a.particles.n == b.particles.n
    assert b.grid.nbytes() == a.grid.nbytes()
    assert np.array_equal(np.asarray(a.grid.shape), np.asarray(b.grid.shape))


def test_a_fluid_only_scene_carries_J_instead_of_F_and_matches_the_F_path(monkeypatch):
    """Every material of the dam break is volumetric, so particles hold J (8 B) and no F.
    Advancing J by det(I + dt grad v) is the determinant of the F update, so the run must
    match the same scene forced onto the F path to round-off."""
    from hpcmpm import simulation

    scene = load_scene("inputs/dam_break_2d.toml", ["simulation.end_time=0.15"])
    fluid = simulate(scene)
    assert set(fluid.particles.field_names()) == {"id", "group", "x", "v", "mass", "vol0", "J",
                                                   "C"}
    # Its return map only resets F, which a J-only scene does not carry: no state phase.
    assert "state" not in fluid.timers.calls
    monkeypatch.setattr(simulation, "deformation_mode", lambda materials, needs_L=False: "F")
    reference = simulate(scene)
    assert "F" in reference.particles and "J" not in reference.particles
    assert fluid.step_index == reference.step_index > 100
    a = np.argsort(fluid.particles["id"])
    b = np.argsort(reference.particles["id"])
    J_ref = np.linalg.det(reference.particles["F"][b])
    # Round-off only: J and det F differ in the last bits each step (different operation
    # order) and feed back through the pressure. Measured after 516 steps: 1.3e-15 in x,
    # 7.8e-15 in J; the bound leaves 1000x for other platforms' arithmetic.
    dx_max = np.abs(fluid.particles["x"][a] - reference.particles["x"][b]).max()
    assert dx_max < 1e-12, dx_max
    assert np.abs(fluid.particles["J"][a] - J_ref).max() < 1e-11
    assert np.abs(J_ref - 1.0).max() > 1e-3  # the check is not vacuous: the fluid compressed


def test_volume_averaging_costs_nothing_unless_asked_for():
    """Without ``volume_averaging`` a J-carrying fluid gets no averaging grid fields and runs
    no averaging phase; with it, both, and the average acts (J differs)."""
    sets = ["simulation.end_time=0.02"]
    plain = simulate(load_scene("inputs/dam_break_2d.toml", sets))
    assert not {"volume_old", "volume_new"} & set(plain.grid.fields)
    assert "volume" not in plain.timers.calls
    assert len(plain._x_old) == 0 and len(plain._J_old) == 0  # no scratch copies either
    averaged = simulate(load_scene("inputs/dam_break_2d.toml",
                                   sets + ['simulation.volume_averaging="increment"']))
    assert {"volume_old", "volume_new"} <= set(averaged.grid.fields)
    assert averaged.timers.calls["volume"] >= averaged.step_index > 5
    a = np.argsort(plain.particles["id"])
    b = np.argsort(averaged.particles["id"])
    assert np.abs(plain.particles["J"][a] - averaged.particles["J"][b]).max() > 1e-6


def test_a_fluid_beside_a_solid_keeps_F_and_stays_isotropic():
    """One material that needs F puts the whole scene on the F path; the fluid's particles
    then carry F, which its state update resets to sqrt(J) I after each G2P."""
    text = Path("inputs/dam_break_2d.toml").read_text() + """
[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1000.0
E = 1.0e5
nu = 0.3

[[bodies]]
name = "ball"
material = "rubber"
shape = "sphere"
center = [0.7, 0.2]
radius = 0.1
"""
    sim = simulate(parse_scene(text, path="<fluid and solid>"), end_time=0.05)
    p = sim.particles
    assert "F" in p and "J" not in p
    assert sim.timers.calls["state"] >= sim.step_index > 5
    water = p["group"] == 0
    assert water.any() and (~water).any()
    F, C = p["F"][water], p["C"][water]
    assert np.abs(np.linalg.det(F) - 1.0).max() > 1e-4  # the column has started to compress
    # The state update after the last G2P reset F to s I (s = sqrt J): no off-diagonal
    # entry survives although the flow shears (C01, C10 nonzero). A fluid F carrying the
    # shear of earlier steps would break this at O(1).
    assert np.abs(C[:, 0, 1]).max() > 0.0 and np.abs(C[:, 1, 0]).max() > 0.0
    assert np.all(F[:, 0, 1] == 0.0) and np.all(F[:, 1, 0] == 0.0)
    assert np.all(F[:, 0, 0] == F[:, 1, 1])


def test_off_grid_peridynamic_bodies_alone_run_no_grid_phase(monkeypatch):
    """Kalthoff-Winkler's plate is off-grid PD with a prescribed impactor (imposed per
    particle, pd/boundary.py): nothing is on the grid, so no block is allocated and no grid
    phase runs, and the run is bit for bit the one that still makes the (empty) grid pass."""
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/kalthoff_winkler_2d.toml", ["simulation.end_time=1e-5"])
    alone = simulate(scene)
    assert alone.step_index > 10 and alone.grid.nbytes() == 0
    assert not {"p2g", "grid", "halo", "g2p", "state"} & set(alone.timers.calls)
    original = Simulation.__init__

    def with_grid(self, *args, **kwargs):
        original(self, *args, **kwargs)
        self.uses_grid = True

    monkeypatch.setattr(Simulation, "__init__", with_grid)
    gridded = simulate(scene)
    assert gridded.grid.nbytes() > 0 and gridded.timers.calls["p2g"] >= gridded.step_index
    a = np.argsort(alone.particles["id"])
    b = np.argsort(gridded.particles["id"])
    assert np.array_equal(alone.particles["x"][a], gridded.particles["x"][b])
    assert np.array_equal(alone.particles["v"][a], gridded.particles["v"][b])
    free = alone.particles["prescribed"] == -1  # the plate outside the impactor's set
    assert free.any() and np.abs(alone.particles["v"][free]).max() > 1.0  # not a run at rest

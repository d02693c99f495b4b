"""A scene pays only for what it uses: fields, kernels and grid memory."""

import numpy as np

from hpcmpm.materials import MATERIALS
from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene


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

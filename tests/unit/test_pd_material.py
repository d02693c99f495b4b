"""The peridynamic material in scenes: bad input gives one line naming the key, and a scene
without PD pays nothing for it."""

import math

import pytest

from hpcmpm.errors import SceneError
from hpcmpm.runner import make_domain
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.simulation import Simulation

PLATE = open("inputs/pd_plate_tear_2d.toml").read()


def sim_with(old: str, new: str) -> Simulation:
    assert old in PLATE
    scene = parse_scene(PLATE.replace(old, new), path="plate.toml")
    return Simulation(scene, make_domain(scene))


@pytest.mark.parametrize("old,new,message", [
    ("nu = 0.25 ", "nu = 0.3 ",
     "material 'glass' (peridynamic): nu: a PMB solid in 2D plane strain has nu = 0.25, "
     "got 0.3"),
    ('model = "pmb"', 'model = "pmb"\nplane = "stress"',
     "nu: a PMB solid in 2D plane stress has nu = 0.333333, got 0.25"),
    ("fracture_energy = 10.0", "fracture_energy = 0.0", "fracture_energy: must be > 0, got 0"),
    ('model = "pmb"', 'model = "pmb"\nhorizon = 0.5', "horizon: must be >= 1, got 0.5"),
    ('model = "pmb"', 'model = "pmb"\nhorizon_length = 0.001',
     "horizon_length: 0.001 is below one particle spacing 0.01"),
    ("[[0.5, 0.7], [0.5, 0.6]]", "[[0.5, 1.7], [0.5, 0.6]]", "precracks[0]: outside the domain"),
    ("[[0.5, 0.7], [0.5, 0.6]]", "[[0.5, 0.7, 0.1], [0.5, 0.6, 0.1]]",
     "precracks[0]: must be a segment of two points [x, y]"),
    ('model = "pmb"', 'model = "correspondence"', "stress_material: missing"),
    ('model = "pmb"', 'model = "correspondence"\nstress_material = "steel"',
     "stress_material: no material named 'steel' (have: glass)"),
    ('integration = "pd"', 'integration = "implicit"', "integration: unknown value"),
    ('model = "pmb"', 'model = "pmb"\npartial_volumes = 1', "partial_volumes: must be true or "
     "false"),
])
def test_bad_input_is_one_line(old, new, message):
    with pytest.raises(SceneError) as err:
        sim_with(old, new)
    assert len(err.value.problems) == 1 and message in err.value.problems[0]


def test_scene_without_pd_pays_nothing():
    scene = load_scene("inputs/disks_2d.toml")
    sim = Simulation(scene, make_domain(scene))
    assert sim.extensions == [] and "x0" not in sim.particles and "damage" not in sim.particles


def test_pd_time_step_rule_and_off_grid_speed():
    sim = sim_with("fracture_energy = 10.0", "fracture_energy = 10.0")
    glass = sim.materials[0]
    assert not glass.on_grid and glass.wave_speed() == 0.0
    # 0.8 sqrt(2 rho / sum_q V_q c w/|X|) over an interior lattice family, written out here:
    # spacing h = dx/ppc = 0.01, V = h^2, c = 12 kappa/(pi delta^3), PA-HHB weights.
    h, delta, rho = 0.01, 3.015 * 0.01, 2500.0
    E, nu = 7.2e10, 0.25
    kappa = E * nu / ((1 + nu) * (1 - 2 * nu)) + E / (2 * (1 + nu))
    c = 12 * kappa / (math.pi * delta ** 3)
    k = 0.0
    for i in range(-4, 5):
        for j in range(-4, 5):
            r = math.hypot(i, j) * h
            if 0 < r < delta + h / 2:
                k += h * h * c * min(1.0, (delta + h / 2 - r) / h) / r
    assert glass.dt_limit(0.02) == pytest.approx(0.8 * math.sqrt(2 * rho / k), rel=1e-12)


def test_bonds_that_would_not_fit_are_refused_before_allocation(monkeypatch):
    import os

    from hpcmpm.runner import initial_particles
    sim = sim_with("fracture_energy = 10.0", "fracture_energy = 10.0")
    initial_particles(sim)
    # A machine of 1 MiB: 1600 particles x 36 half-bonds x 25 B do not fit in half of it.
    monkeypatch.setattr(os, "sysconf", lambda name: 1024 if name == "SC_PAGE_SIZE" else 1024)
    sim.ensure_grouped()
    with pytest.raises(SceneError, match="36 half-bonds per particle need about"):
        sim.extensions[0].prepare()


@pytest.mark.parametrize("condition", ["slip", "sticky"])
def test_off_grid_pd_body_stops_at_a_wall(condition):
    from hpcmpm.runner import simulate
    text = PLATE.replace('velocity = [-20.0, 0.0]', 'velocity = [0.0, -300.0]') \
        .replace('velocity = [20.0, 0.0]', 'velocity = [0.0, -300.0]') \
        .replace('lower = [0.3, 0.3]', 'lower = [0.3, 0.02]') \
        .replace('lower = [0.5, 0.3]', 'lower = [0.5, 0.02]') \
        .replace('default = "slip"', f'default = "{condition}"')
    scene = parse_scene(text, path="plate.toml")
    sim = simulate(scene, end_time=2e-4)        # 0.06 m of travel: the plate (at 0.02) lands
    y = sim.particles["x"][:, 1]
    # The lowest layer (at 0.025 initially) reached the floor and stopped on it.
    assert y.min() >= 0.0 and y.min() < 0.01

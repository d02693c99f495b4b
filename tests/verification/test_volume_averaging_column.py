"""A fluid column at rest under gravity keeps its hydrostatic state with volume averaging
(``simulation.volume_averaging = "increment"``): averaging the step's change of J leaves a state
at rest a fixed point, so the column settles as it does without the average.

Weakly compressible fluid (tau = E (J - 1) I), rho0 = 1000, E = 1e5, g = 9.81, height
H = 0.5, periodic along x, slip floor, semi-implicit (backward Euler damps the release
waves). In the reference coordinate Y the column's weight above Y gives the Cauchy pressure
p = rho0 g (H - Y) exactly (each layer keeps its mass), and p = E (1 - J) / J, so
J(Y) = 1 / (1 + rho0 g (H - Y) / E): a compression of up to rho0 g H / E = 4.9 %.

Measured at t = 3 (dt = 0.01): max |v| 1.7e-7 with the average and 7e-8 without; interior
J (0.1 < Y < 0.4, two cells from the floor and the surface) within 0.5 % and 0.6 % of that
compression of the closed form. The test asks 1e-5 and 2 %: settled, and at the closed form
to a small part of the compression that MPM's boundary layers (about 20 % of it in the first
cell above the floor, with or without the average) leave alone in the interior. An average
of J itself instead of its change (tried: docs/studies.md) kept |v| at 7e-4 here."""

import functools

import numpy as np
import pytest

from hpcmpm.runner import initial_particles, make_domain, simulate
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

RHO, E, G, H = 1000.0, 1.0e5, 9.81, 0.5
TEXT = f"""
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [0.25, 1.0] }}
dx = 0.015625
particles_per_cell = 2
integrator = "semi_implicit"
dt = 0.01
end_time = 3.0
gravity = [0.0, {-G}]
periodic = ["x"]

[solver]
tolerance = 1e-10

[[materials]]
name = "water"
type = "weakly_compressible"
density = {RHO}
E = {E}

[[bodies]]
name = "column"
material = "water"
shape = "box"
lower = [0.0, 0.0]
upper = [0.25, {H}]

[walls]
default = "slip"
"""


@functools.lru_cache(maxsize=None)
def settled(averaging: str):
    """(Y of each particle, final J, max |v|, steps), rows sorted by id."""
    scene = parse_scene(TEXT, "column.toml", [f'simulation.volume_averaging="{averaging}"'])
    # The reference coordinate of each particle: its place in the lattice before the run.
    probe = Simulation(scene, make_domain(scene))
    initial_particles(probe)
    reference = dict(zip(probe.particles["id"].tolist(), probe.particles["x"][:, 1].tolist()))
    sim = simulate(scene)
    p = sim.particles
    order = np.argsort(p["id"])
    Y = np.array([reference[i] for i in p["id"][order].tolist()])
    return Y, p["J"][order].copy(), float(np.abs(p["v"]).max()), sim.step_index


@pytest.mark.parametrize("averaging", ["increment", "none"])
def test_column_settles_to_the_hydrostatic_state(averaging):
    Y, J, vmax, steps = settled(averaging)
    assert steps == 300
    exact = 1.0 / (1.0 + RHO * G * (H - Y) / E)
    scale = RHO * G * H / E
    assert vmax < 1e-5
    interior = (Y > 0.1) & (Y < 0.4)
    assert interior.sum() > 200
    assert np.abs(J[interior] - exact[interior]).max() < 0.02 * scale
    # The column did compress: the check is not vacuous.
    assert (1.0 - J[interior]).max() > 0.5 * scale


def test_the_average_acts():
    """"increment" is not "none" renamed: the two settled columns' J differ (measured up to
    5.9e-3, 12 % of the compression, mostly in the boundary layers)."""
    scale = RHO * G * H / E
    assert np.abs(settled("increment")[1] - settled("none")[1]).max() > 0.05 * scale

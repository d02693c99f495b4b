"""The engine's extension points: deformation modes, the state update after G2P, the force
channel into P2G, materials off the grid, and non-numeric material parameters."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hpcmpm import simulation
from hpcmpm.materials import MATERIALS
from hpcmpm.materials.params import Param, check_params, choice, resolve_params, table
from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene, parse_scene


def test_mode_L_reproduces_the_F_path_bitwise(monkeypatch):
    """In mode L, G2P stores L_p and the material advances F <- (I + dt L_p) F itself: the
    same products in the same order as G2P's own update, so the runs agree bit for bit."""
    overrides = ["simulation.end_time=0.1"]
    plain = simulate(load_scene("inputs/jelly_cube_3d.toml", overrides + ["simulation.dx=0.1"]))
    monkeypatch.setattr(simulation, "deformation_mode", lambda materials, needs_L=False: "L")
    with_L = simulate(load_scene("inputs/jelly_cube_3d.toml", overrides + ["simulation.dx=0.1"]))
    assert plain.deformation == "F" and with_L.deformation == "L"
    assert "L" in with_L.particles and "L" not in plain.particles
    a, b = plain.particles, with_L.particles
    ia, ib = np.argsort(a["id"]), np.argsort(b["id"])
    assert plain.step_index == with_L.step_index > 5
    for name in ("x", "v", "F", "C"):
        assert np.array_equal(a[name][ia], b[name][ib]), name
    # L is the velocity gradient of the last step: for MLS that is C (Hu 2018).
    assert np.array_equal(b["L"], b["C"])


def test_snow_frames_hold_the_projected_state():
    """The clamp runs right after G2P, so between steps every F_E lies inside
    [1 - theta_c, 1 + theta_s] (before, the state between steps was the trial F_E)."""
    scene = load_scene("inputs/snow_block_3d.toml",
                       ["simulation.end_time=0.12", "simulation.dx=0.05"])
    sim = simulate(scene)
    spec = scene.materials[0].params
    sigma = np.linalg.svd(sim.particles["F"], compute_uv=False)
    # Reassembling U Sigma_c V^T rounds: a few ulps of slack on the clamp bounds.
    assert sigma.min() >= 1 - spec["theta_c"] - 1e-14
    assert sigma.max() <= 1 + spec["theta_s"] + 1e-14
    assert np.any(sim.particles["Jp"] != 1.0)  # the clamp did act: the check is not vacuous


class ConstantForce:
    """A step extension that pushes every particle with the same force f."""

    def __init__(self, f):
        self.f = np.asarray(f, dtype=np.float64)
        self.calls = 0

    def particle_forces(self, sim, dt):
        self.calls += 1
        n = sim.particles.n
        yield 0, n, np.tile(self.f, (n, 1))


@pytest.mark.parametrize("transfer", ["mls", "flip"])
def test_force_channel_adds_dt_sum_f_to_the_momentum(transfer):
    """Partition of unity: sum_i w_ip = 1, so the force channel adds exactly dt sum_p f_p to
    the total momentum per step. The disks move apart in free space (no walls reached), so
    nothing else changes the momentum; both transfers conserve it to round-off otherwise."""
    scene = load_scene("inputs/disks_2d.toml", ["simulation.end_time=0.02",
                                                f'simulation.transfer="{transfer}"'])
    force = ConstantForce([0.3, -0.2])
    steps = []

    def observe(sim):
        steps.append((sim.time, sim.diagnostics()["momentum"][:2].copy()))

    from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain

    sim = simulation.Simulation(scene, make_domain(scene))
    sim.add_extension(force)
    initial_particles(sim)
    p0 = sim.diagnostics()["momentum"][:2].copy()
    n = sim.domain.sum(sim.particles.n)
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=0.02, quiet=True),
           observer=observe).run()
    t, p = steps[-1]
    expected = p0 + t * n * force.f
    assert force.calls == sim.step_index > 3
    # Round-off of n * steps additions of O(|p|) terms.
    assert np.abs(p - expected).max() <= 1e-12 * (np.abs(p0).max() + np.abs(expected).max())
    assert np.abs(expected - p0).max() > 1e-3 * np.abs(p0).max()  # the force is not lost



def test_stable_dt_is_the_cfl_bound_with_the_wave_and_particle_speeds_added():
    """Explicit CFL: dt = cfl dx / (c_max + |v|_max), c the P-wave speed
    sqrt((lambda + 2 mu) / rho) (plane-strain Lame pair from E, nu), computed here from the
    scene, |v|_max from the particles. The neo-Hookean rubber has no viscous bound and
    max_dt is the runner's, not stable_dt's. c = 1.160 and |v| = 0.141, so a bound from
    max(c, |v|) instead of the sum would be 1.122 times too large. The two sides agreed
    exactly (relative difference 0.0 measured); 1e-12 only leaves room for round-off."""
    from hpcmpm.runner import initial_particles, make_domain

    scene = load_scene("inputs/disks_2d.toml", ["simulation.end_time=0.02"])
    (mat,) = scene.materials
    E, nu, rho = mat.params["E"], mat.params["nu"], mat.density
    mu, lam = E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    c = math.sqrt((lam + 2.0 * mu) / rho)
    assert c == pytest.approx(1.1602, abs=1e-4)
    sim = simulation.Simulation(scene, make_domain(scene))
    initial_particles(sim)
    for step in range(4):  # the disks move; then one particle is sped up to |v| = 0.5
        if step == 3:
            sim.particles["v"][7] = [0.3, -0.4]
        vmax = np.linalg.norm(sim.particles["v"], axis=1).max()
        assert vmax == pytest.approx(0.5 if step == 3 else 0.1 * math.sqrt(2.0), rel=1e-12)
        dt = sim.stable_dt()
        assert dt == pytest.approx(scene.cfl * sim.dx / (c + vmax), rel=1e-12, abs=0.0)
        sim.step(dt)

def test_materials_off_the_grid_are_not_transferred(monkeypatch):
    """A material with on_grid = False (a peridynamic body that moves by its own bond forces)
    is skipped by P2G, G2P and the state update: the step leaves its particles untouched,
    while the other body falls under gravity."""
    text = Path("inputs/disks_2d.toml").read_text() + """
[[materials]]
name = "off_grid"
type = "linear_elastic"
density = 1000.0
E = 1.0e5
nu = 0.3

[[bodies]]
name = "block"
material = "off_grid"
shape = "box"
lower = [0.05, 0.05]
upper = [0.15, 0.15]
"""
    scene = parse_scene(text, "<disks and an off-grid block>", ["simulation.end_time=0.01",
                                                                "simulation.gravity=[0, -9.8]"])
    monkeypatch.setattr(MATERIALS["linear_elastic"], "on_grid", False)
    from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain

    sim = simulation.Simulation(scene, make_domain(scene))
    initial_particles(sim)
    start = {k: v.copy() for k, v in sim.particles.snapshot().items()}
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=0.01, quiet=True)).run()
    p = sim.particles
    order, order0 = np.argsort(p["id"]), np.argsort(start["id"])
    off = p["group"][order] == 1
    assert off.any() and (~off).any() and sim.step_index > 3
    for name in ("x", "v", "F"):
        assert np.array_equal(p[name][order][off], start[name][order0][off]), name
    assert not np.array_equal(p["v"][order][~off], start["v"][order0][~off])


def test_parameter_kinds():
    schema = {
        "mu": Param(0.0, math.inf, low_inclusive=True),
        "relaxation_time": Param(0.0, math.inf, required=False, default=math.inf,
                                 high_inclusive=True),
        "plasticity": choice(("ob_spd", "ob_explicit"), "ob_spd"),
        "eos": table({"c0": Param(0.0, math.inf), "s": Param(1.0, math.inf, required=False,
                                                              default=1.1)}),
    }
    assert check_params(schema, {"mu": 1.0, "relaxation_time": math.inf}) == []
    assert check_params(schema, {"mu": 1.0, "plasticity": "ob_sdp"}) == [
        "plasticity: unknown value 'ob_sdp' (did you mean 'ob_spd'? valid: ob_spd, "
        "ob_explicit)"]
    assert check_params(schema, {"mu": 1.0, "plasticity": 3.0}) == [
        "plasticity: must be a string, one of ob_spd, ob_explicit; got float 3.0"]
    assert check_params(schema, {"mu": 1.0, "eos": {"c0": -1.0, "S": 2}}) == [
        "eos.S: unknown key (did you mean 's'?)", "eos.c0: must be > 0, got -1"]
    assert check_params(schema, {"mu": math.inf}) == ["mu: must be finite, got inf"]
    assert check_params(schema, {"mu": 1.0, "eos": 3}) == [
        "eos: must be a table ({key = value, ...}), got int 3"]
    values = resolve_params(schema, {"mu": 2, "eos": {"c0": 5}})
    assert values == {"mu": 2.0, "relaxation_time": math.inf, "plasticity": "ob_spd",
                      "eos": {"c0": 5.0, "s": 1.1}}


def test_scene_reports_a_bad_material_string_with_its_path():
    text = Path("inputs/disks_2d.toml").read_text()
    with pytest.raises(Exception) as info:
        parse_scene(text, "disks.toml", ['materials.0.E="stiff"'])
    assert "disks.toml: materials[0].E: must be a number, got string 'stiff'" in str(info.value)


def test_solver_table_and_integrator_are_validated():
    text = Path("inputs/disks_2d.toml").read_text()
    with pytest.raises(Exception) as info:
        parse_scene(text, "d.toml", ['simulation.integrator="implicitt"', 'solver.mode="nwton"',
                                     "solver.tolerance=2.0", "solver.max_iterations=0"])
    message = str(info.value)
    assert "d.toml: simulation.integrator: unknown value 'implicitt'" in message
    assert "d.toml: solver.mode: unknown value 'nwton' (did you mean 'newton'?" in message
    assert "d.toml: solver.tolerance: must be < 1.0, got 2.0" in message
    assert "d.toml: solver.max_iterations: must be >= 1, got 0" in message
    scene = parse_scene(text, "d.toml", ['solver.mode="newton"'])
    assert scene.solver.mode == "newton" and scene.solver.preconditioner == "jacobi"
    assert scene.integrator == "explicit"



def _falling_cube_energies(cfl: float):
    scene = load_scene("inputs/jelly_cube_3d.toml", ["simulation.dx=0.05",
                                                      f"simulation.cfl={cfl}"])
    seen = []
    simulate(scene, end_time=0.15, observer=lambda sim: seen.append(sim.diagnostics()))
    return seen[0], seen[-1]


def test_total_energy_counts_gravity():
    """A falling elastic cube (before it reaches the floor) trades gravitational for kinetic
    and elastic energy: total_energy = kinetic + elastic + gravity (-sum m g.x) stays put
    to first order in dt, while kinetic + elastic alone grows by the whole drop m g dz.
    Symplectic Euler (v then x with the new v) loses m |g|^2 dt^2 / 2 a step in free fall,
    a drift of about dt/T of the drop over a time T: measured 1.97 % at cfl 0.4 (50
    steps) and 1.03 % at cfl 0.2 (99 steps)."""
    drift = []
    for cfl in (0.4, 0.2):
        first, last = _falling_cube_energies(cfl)
        drop = last["gravity_energy"] - first["gravity_energy"]
        assert drop < 0.0
        moving = (last["kinetic_energy"] + last["elastic_energy"]
                  - first["kinetic_energy"] - first["elastic_energy"])
        assert moving == pytest.approx(-drop, rel=0.05)   # the check below is not vacuous
        drift.append((last["total_energy"] - first["total_energy"]) / -drop)
    # First order: halving the step halves the drift (1.90 measured); a missing or wrong
    # term would leave a drift of order 1 that does not shrink with dt.
    assert abs(drift[1]) < 0.015 and 1.6 < drift[0] / drift[1] < 2.4, drift

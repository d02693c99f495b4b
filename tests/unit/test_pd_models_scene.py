"""Scene keys of the 003 ch. 5 peridynamic models (hpcmpm/materials/pd_models.py): bad input
is one line naming the key; the keys build the right model objects with the issue's
constants (beta, the time-step micromodulus) and the crack-plane extension."""

import math

import numpy as np
import pytest

from hpcmpm.errors import SceneError
from hpcmpm.materials import make_material
from hpcmpm.pd.bond_energy import BondEnergy
from hpcmpm.pd.families import full_family_sum
from hpcmpm.pd.viscoelastic_lps import ViscoelasticLPS
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

PLATE = open("inputs/pd_plate_tear_2d.toml").read()


def sim_with(old: str, new: str) -> Simulation:
    assert old in PLATE
    scene = parse_scene(PLATE.replace(old, new), path="plate.toml")
    return Simulation(scene, make_domain(scene))


@pytest.mark.parametrize("old,new,message", [
    ('model = "pmb"', 'model = "pmb"\nplastic_yield = 1.0',
     "plastic_yield: only for model = bond_energy (got model = 'pmb')"),
    ('model = "pmb"', 'model = "lps"\nrelaxation_time = 1.0',
     "relaxation_time: only for model = viscoelastic_lps (got model = 'lps')"),
    ('model = "pmb"', 'model = "bond_energy"\nmemory = "none"',
     "memory: only for model = viscoelastic_lps"),
    ('model = "pmb"', 'model = "viscoelastic_lps"\nmemory = "all"', "memory: unknown value"),
    ('model = "pmb"', 'model = "viscoelastic_lps"\nrelaxation_time = -1.0',
     "relaxation_time: must be > 0"),
    ('model = "pmb"', 'model = "bond_energy"\nplastic_yield = -1.0',
     "plastic_yield: must be > 0"),
    ('model = "pmb"', 'model = "pmb"\ncrack_threshold = 0.05',
     "crack_threshold: crack planes replace the stretch criterion; remove fracture_energy"),
    ('model = "pmb"', 'model = "pmb"\ntwo_time_integration = 1',
     "two_time_integration: must be true or false"),
])
def test_bad_input_is_one_line(old, new, message):
    with pytest.raises(SceneError) as err:
        sim_with(old, new)
    assert len(err.value.problems) == 1 and message in err.value.problems[0]


def configured(text: str):
    scene = parse_scene(text, path="scene.toml")
    material = make_material(scene.materials[0], scene.dim)
    material.configure(scene)
    return scene, material


def test_bond_energy_keys_build_the_model_with_beta():
    scene, mat = configured(PLATE.replace('model = "pmb"', 'model = "bond_energy"\n'
                                          'plastic_yield = 100.0').replace("nu = 0.25 ",
                                                                           "nu = 0.3 "))
    model = mat.make_model()
    assert isinstance(model, BondEnergy) and model.psi_p == 100.0
    lam, mu, h, delta = mat.lam, mat.mu, mat.spacing, mat.delta
    # beta = d^2 K / ((2 mu + lambda) sum_q w V_q), K = lambda + mu (2D), full family.
    want = 4 * (lam + mu) / ((2 * mu + lam) * full_family_sum(2, h, delta))
    assert abs(model.beta / want - 1) < 1e-14
    E, nu = mat.params["E"], mat.params["nu"]
    assert abs(lam / (E * nu / ((1 + nu) * (1 - 2 * nu))) - 1) < 1e-12
    assert 0 < mat.dt_limit(scene.dx) < math.inf


def test_viscoelastic_keys_build_the_model():
    scene, mat = configured(PLATE.replace('model = "pmb"', 'model = "viscoelastic_lps"\n'
                                          'relaxation_time = 0.5\nmemory = "none"')
                            .replace("nu = 0.25 ", "nu = 0.3 "))
    model = mat.make_model()
    assert isinstance(model, ViscoelasticLPS)
    assert (model.tau, model.memory, model.mu) == (0.5, "none", mat.mu)
    decay, gain = ViscoelasticLPS(1.0, 1.0, relaxation_time=2.0).relaxation(0.1)
    assert decay == math.exp(-0.05) and abs(gain - (1 - math.exp(-0.05)) / 0.05) < 1e-15


def test_crack_threshold_selects_the_crack_plane_extensions():
    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM, CrackPlanePDBody

    text = PLATE.replace("fracture_energy = 10.0", "crack_threshold = 0.05")
    sim = Simulation(parse_scene(text, path="s.toml"),
                     make_domain(parse_scene(text, path="s.toml")))
    assert any(isinstance(e, CrackPlanePDBody) for e in sim._after_g2p)
    text = text.replace('integration = "pd"', 'integration = "grid"')
    scene = parse_scene(text, path="s.toml")
    sim = Simulation(scene, make_domain(scene))
    assert any(isinstance(e, CrackPlaneIntegralMPM) for e in sim._force_sources)


@pytest.mark.parametrize("per_cell", [1, 2])
def test_crack_planes_cut_within_max_of_cell_and_horizon(per_cell):
    """003 §5.4 as the issue corrects it: bonds crossing a crack plane within max(dx, delta)
    break. The engine passes that radius: delta = 3.015 spacings is 3.015 dx with one
    particle per cell and 1.5075 dx with two, so either way a radius of dx would be wrong."""
    from hpcmpm.pd.crack_planes import _crack_planes_of

    text = (PLATE.replace("fracture_energy = 10.0", "crack_threshold = 0.05")
            .replace("particles_per_cell = 2", f"particles_per_cell = {per_cell}"))
    scene = parse_scene(text, path="s.toml")
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    (ext,) = [e for e in sim._after_g2p if hasattr(e, "compute_forces")]
    delta = 3.015 * scene.dx / per_cell        # the default horizon, in the scene's units
    assert _crack_planes_of(ext).radius == pytest.approx(max(scene.dx, delta), rel=1e-12)


def test_two_time_integration_moves_cracked_particles_by_their_own_force():
    """003 §5.4's two-time integration: on the grid, particles with a broken bond leave the
    grid's update and take a symplectic Euler step by their own PD force f, v = v^n + dt (f/m
    + g), x = x^n + dt v, from the state before the step (`CrackPlaneIntegralMPM.after_g2p`);
    every other particle keeps what G2P gave it. Unit test on the method alone (the walls
    stubbed out; they are tested in test_pd_colliders.py)."""
    from types import SimpleNamespace

    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM

    rng = np.random.default_rng(4)
    p = {"x": rng.random((6, 2)), "v": rng.random((6, 2)), "mass": rng.uniform(1.0, 2.0, 6)}
    grid_update = {k: p[k].copy() for k in ("x", "v")}
    at = np.array([1, 4])
    x_n, v_n, f = rng.random((2, 2)), rng.random((2, 2)), rng.normal(size=(2, 2))
    ext = object.__new__(CrackPlaneIntegralMPM)
    ext._own = (at, x_n.copy(), v_n.copy(), f.copy())
    ext.walls = SimpleNamespace(apply=lambda x, v, dt: None)
    g, dt = np.array([0.0, -10.0, 0.0]), 0.1
    ext.after_g2p(SimpleNamespace(particles=p, gravity=g, dim=2), dt)
    v = v_n + dt * (f / p["mass"][at, None] + g[:2])
    # The same operations in the same order: bitwise.
    assert np.array_equal(p["v"][at], v) and np.array_equal(p["x"][at], x_n + dt * v)
    rest = np.setdiff1d(np.arange(6), at)
    for k in ("x", "v"):
        assert np.array_equal(p[k][rest], grid_update[k][rest])
    assert ext._own is None                    # used once

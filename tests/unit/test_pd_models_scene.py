"""Scene keys of the 003 ch. 5 peridynamic models (hpcmpm/materials/pd_models.py): bad input
is one line naming the key; the keys build the right model objects with the issue's
constants (beta, the time-step micromodulus) and the crack-plane extension."""

import math

import numpy as np
import pytest

from hpcmpm.errors import SceneError
from hpcmpm.materials import make_material
from hpcmpm.pd.bond_energy import PLASTIC_STATE, BondEnergy, yield_energy_of_stretch
from hpcmpm.pd.families import full_family_sum
from hpcmpm.pd.viscoelastic_lps import ViscoelasticLPS
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import load_scene, parse_scene
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
    ('model = "pmb"', 'model = "pmb"\nplastic_yield_stretch = 0.01',
     "plastic_yield_stretch: only for model = bond_energy (got model = 'pmb')"),
    ('model = "pmb"', 'model = "bond_energy"\nplastic_yield_stretch = 0.0',
     "plastic_yield_stretch: must be > 0"),
    ('model = "pmb"', 'model = "bond_energy"\nplastic_yield = 1.0\nplastic_yield_stretch = 0.01',
     "plastic_yield_stretch: sets the same yield as plastic_yield (psi_p); give one of them"),
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


def test_yield_stretch_key_sets_psi_p_at_the_materials_horizon():
    """``plastic_yield_stretch`` reaches the model as the psi_p of a bond of length delta
    (this material's horizon, not its spacing) and unit influence yielding at s_y; at half
    the dx it is 2^(2d + 2) = 64 times larger (2D), where ``plastic_yield`` stays put."""
    text = PLATE.replace('model = "pmb"', 'model = "bond_energy"\nplastic_yield_stretch = '
                         '0.01').replace("nu = 0.25 ", "nu = 0.3 ")
    psi = []
    assert "dx = 0.02\n" in text
    for dx in ("0.02", "0.01"):
        scene, mat = configured(text.replace("dx = 0.02\n", f"dx = {dx}\n"))
        model = mat.make_model()
        s = mat.delta / (model.beta * (2 * mat.mu + mat.lam) * 0.01)
        assert abs(0.5 / (s * s) / model.psi_p - 1) < 1e-14
        assert PLASTIC_STATE in mat.bond_state_names()
        psi.append(model.psi_p)
    assert abs(psi[1] / psi[0] / 64 - 1) < 1e-12


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
    every other particle keeps what G2P gave it. Unit test on the method alone (the off-grid
    boundaries stubbed out; tested below and in test_pd_colliders.py)."""
    from types import SimpleNamespace

    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM

    rng = np.random.default_rng(4)
    p = {"x": rng.random((6, 2)), "v": rng.random((6, 2)), "mass": rng.uniform(1.0, 2.0, 6)}
    grid_update = {k: p[k].copy() for k in ("x", "v")}
    at = np.array([1, 4])
    x_n, v_n, f = rng.random((2, 2)), rng.random((2, 2)), rng.normal(size=(2, 2))
    ext = object.__new__(CrackPlaneIntegralMPM)
    ext._own = (at, x_n.copy(), v_n.copy(), f.copy())
    ext.boundaries = SimpleNamespace(apply=lambda sim, rows, x, v, dt: None)
    g, dt = np.array([0.0, -10.0, 0.0]), 0.1
    ext.after_g2p(SimpleNamespace(particles=p, gravity=g, dim=2), dt)
    v = v_n + dt * (f / p["mass"][at, None] + g[:2])
    # The same operations in the same order: bitwise.
    assert np.array_equal(p["v"][at], v) and np.array_equal(p["x"][at], x_n + dt * v)
    rest = np.setdiff1d(np.arange(6), at)
    for k in ("x", "v"):
        assert np.array_equal(p[k][rest], grid_update[k][rest])
    assert ext._own is None                    # used once


def test_two_time_integration_takes_the_particles_with_a_broken_bond():
    """`CrackPlaneIntegralMPM.particle_forces` keeps, for `after_g2p`, the rows of the
    group with damage > 0 (a broken bond) with their x^n, v^n and force, and only those;
    none with ``two_time_integration = false``. The parent's force pass is stubbed: the
    damage values include exact zeros next to tiny positive ones."""
    from types import SimpleNamespace

    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM
    from hpcmpm.pd.extension import IntegralMPMExtension

    rng = np.random.default_rng(8)
    n, start, stop = 12, 3, 10
    damage = np.zeros(n)
    damage[[1, 4, 7, 9, 11]] = [0.5, 1e-12, 0.25, 1.0, 0.3]     # rows 1 and 11 not in the group
    p = {"x": rng.random((n, 2)), "v": rng.random((n, 2)), "damage": damage}
    f = rng.normal(size=(stop - start, 2))

    def parent(self, sim, dt):
        yield start, stop, f

    for two_time in (True, False):
        ext = object.__new__(CrackPlaneIntegralMPM)
        ext.material = SimpleNamespace(params={"two_time_integration": two_time})
        original = IntegralMPMExtension.particle_forces
        IntegralMPMExtension.particle_forces = parent
        try:
            out = list(ext.particle_forces(SimpleNamespace(particles=p), 0.1))
        finally:
            IntegralMPMExtension.particle_forces = original
        assert len(out) == 1 and out[0][2] is f
        if not two_time:
            assert ext._own is None
            continue
        at, x_n, v_n, f_own = ext._own
        assert at.tolist() == [4, 7, 9]
        assert np.array_equal(x_n, p["x"][at]) and np.array_equal(v_n, p["v"][at])
        assert np.array_equal(f_own, f[at - start])


def test_two_time_integration_stops_cracked_particles_at_the_walls():
    """Off the grid, the domain walls act on the particles of the two-time integration per
    particle (contact.py), before their position update: a particle about to cross the
    slip floor loses its normal velocity and lands on x^n + dt v with v_y = 0; one about to
    cross the slip side wall loses v_x; one in the interior keeps v^n + dt (f/m + g)."""
    from types import SimpleNamespace

    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM

    scene = parse_scene(PLATE, path="plate.toml")        # walls: default = "slip"
    dt = 1e-3
    x_n = np.array([[0.5, 0.004], [0.996, 0.5], [0.5, 0.5]])
    v_n = np.array([[3.0, -10.0], [10.0, 2.0], [3.0, -10.0]])
    f = np.zeros((3, 2))
    p = {"x": np.zeros((3, 2)), "v": np.zeros((3, 2)), "mass": np.ones(3)}
    ext = object.__new__(CrackPlaneIntegralMPM)
    ext._own = (np.arange(3), x_n.copy(), v_n.copy(), f)
    g = np.zeros(3)
    ext.after_g2p(SimpleNamespace(particles=p, gravity=g, dim=2, scene=scene, time=0.0), dt)
    want_v = np.array([[3.0, 0.0], [0.0, 2.0], [3.0, -10.0]])
    assert np.array_equal(p["v"], want_v)
    assert np.array_equal(p["x"], x_n + dt * want_v)
    assert p["x"][:, 1].min() >= 0.0 and p["x"][:, 0].max() <= 1.0


COLLIDER = """
[[colliders]]
shape = "sphere"
center = [0.5, 0.5]
radius = 0.1
condition = "sticky"
"""


def test_two_time_integration_applies_the_colliders_and_prescribed_sets():
    """Off the grid the colliders and prescribed sets act per particle too, as on off-grid PD
    bodies (pd/boundary.py): particle 0 at x = 0.395 moving at +10 toward a sticky sphere
    whose surface is at x = 0.4 would end inside it (0.405 after dt = 1e-3) and takes the
    sphere's velocity, 0; particle 1, in a prescribed set (V = (0.5, -1), omega = 2 about
    c(t) = (0.2, 0.2) + V t), takes the set's rigid velocity at x^n, whatever its own force;
    particle 2, free and far from both, keeps v^n + dt f/m. Before the fix the two-time step
    applied the walls alone: particle 0 kept v = (10, 0) and entered the sphere, particle 1
    left its set."""
    from types import SimpleNamespace

    from hpcmpm.boundaries.prescribed import PrescribedSet
    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM

    scene = parse_scene(PLATE + COLLIDER, path="plate.toml")
    spec = SimpleNamespace(region={"lower": [0.0, 0.0], "upper": [0.4, 0.4]},
                           velocity=[0.5, -1.0], angular_velocity=2.0, center=[0.2, 0.2])
    dt, t = 1e-3, 0.25
    x_n = np.array([[0.395, 0.5], [0.3, 0.25], [0.8, 0.8]])
    v_n = np.array([[10.0, 0.0], [4.0, 4.0], [1.0, 2.0]])
    f = np.array([[0.0, 0.0], [5.0, 5.0], [3.0, -1.0]])
    p = {"x": np.zeros((4, 2)), "v": np.zeros((4, 2)), "mass": np.full(4, 2.0),
         "prescribed": np.array([-1, -1, 0, -1], np.int32)}
    ext = object.__new__(CrackPlaneIntegralMPM)
    at = np.array([0, 2, 3])                 # rows of the particle set, not contiguous
    ext._own = (at, x_n.copy(), v_n.copy(), f.copy())
    sim = SimpleNamespace(particles=p, gravity=np.zeros(3), dim=2, scene=scene, time=t,
                          prescribed=[PrescribedSet(spec, 0, 2)])
    ext.after_g2p(sim, dt)
    c = np.array([0.2, 0.2]) + np.array([0.5, -1.0]) * t
    r = x_n[1] - c
    rigid = np.array([0.5, -1.0]) + 2.0 * np.array([-r[1], r[0]])
    # Rows 0 and 2: exact values; row 3: the same operations as the test's (bitwise).
    assert np.array_equal(p["v"][0], [0.0, 0.0])
    np.testing.assert_allclose(p["v"][2], rigid, rtol=0, atol=1e-15)
    assert np.array_equal(p["v"][3], v_n[2] + dt * f[2] / 2.0)
    assert np.array_equal(p["x"][at], x_n + dt * p["v"][at])
    assert np.array_equal(p["v"][1], [0.0, 0.0])          # not in the two-time rows


def test_crack_planes_see_the_bonds_plastic_stretch():
    """With bond plasticity (``model = "bond_energy"``), l = (s - e_p) / (1 + p_bar) reads
    the bonds' plastic stretch (`CrackPlaneForces.compute_forces`): under a uniform stretch
    of 2 l_threshold every bond would break, but a plastic stretch of 1.5 l_threshold on
    every bond keeps them all (l = 0.5 l_threshold)."""
    from hpcmpm.pd.crack_planes import CrackPlanes

    from hpcmpm.pd.crack_planes import CrackPlaneIntegralMPM

    text = open("inputs/ibmpm_wall_fracture_2d.toml").read()
    threshold = 0.05
    assert f"crack_threshold = {threshold}" in text
    scene = parse_scene(text, path="wall.toml")
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    sim.ensure_grouped()
    (ext,) = [e for e in sim._force_sources if isinstance(e, CrackPlaneIntegralMPM)]
    start, stop = ext.prepare()
    seen = []
    original = CrackPlanes.apply

    def spy(self, pts, comm, plastic=None):
        seen.append(plastic)
        return original(self, pts, comm, plastic)

    CrackPlanes.apply = spy
    try:
        ext.bonds.state["plastic_stretch"][:] = 1.5 * threshold
        x0 = ext.pts.x0
        ext.pts.x[:] = x0 + 2.0 * threshold * (x0 - x0.mean(axis=0))
        ext.compute_forces(start, stop)
    finally:
        CrackPlanes.apply = original
    assert len(seen) == 1 and seen[0] is ext.bonds.state["plastic_stretch"]
    assert ext.crack_planes.planes == 0 and np.all(ext.bonds.status == 1)


@pytest.mark.parametrize("key, value", [("plastic_yield_stretch", 0.0123),
                                        ("plastic_yield", None)])
def test_run_log_gives_the_yield_stretch_of_psi_p(caplog, key, value):
    """The run log names psi_p with the yield stretch it amounts to at the run's spacing
    (psi_p's unit depends on the horizon): given as a stretch, the same stretch comes back;
    given as psi_p, the logged stretch gives psi_p back."""
    import re

    from hpcmpm.runner import simulate

    sets = ["materials.wall.plastic_yield=inf", f"materials.wall.{key}={value}"] \
        if value is not None else []
    with caplog.at_level("INFO", logger="hpcmpm"):
        sim = simulate(load_scene("inputs/ibmpm_wall_fracture_2d.toml", sets), end_time=1e-9)
    said = [r.getMessage() for r in caplog.records if "bond plasticity" in r.getMessage()]
    assert len(said) == 1
    got = re.search(r"psi_p = (\S+), the yield stretch s_y = (\S+) of a bond of length "
                    r"delta = (\S+) ", said[0])
    psi_p, s_y, delta = (float(g) for g in got.groups())
    model = sim.extensions[0].model
    assert abs(psi_p / model.psi_p - 1) < 1e-5 and abs(delta / 0.015075 - 1) < 1e-5
    # The logged stretch gives back psi_p through the forward rule, which the verification
    # tests check against the bonds' yield (to the log's 6 digits: 1e-5, twice for psi_p).
    back = yield_energy_of_stretch(model.beta, model.lam, model.mu, delta, s_y)
    assert abs(back / model.psi_p - 1) < 2e-5
    if value is not None:
        assert abs(s_y / value - 1) < 1e-5
    else:
        assert s_y < 1e-9       # psi_p = 500 (Table 5.1): perfectly plastic, as the file says


def test_validate_names_the_yield_stretch_of_bond_plasticity():
    """`hpcmpm validate` prints the same line as the run log for a bond-plastic body, and
    nothing of the kind for a scene without one."""
    from hpcmpm.startup import validate_report

    report = validate_report(load_scene("inputs/ibmpm_wall_fracture_2d.toml"))
    lines = [line for line in report.splitlines() if "bond plasticity" in line]
    assert len(lines) == 1 and lines[0].startswith(
        "inputs/ibmpm_wall_fracture_2d.toml: material 'wall': bond plasticity psi_p = 500, "
        "the yield stretch s_y = ")
    for scene in ("inputs/pd_plate_tear_2d.toml", "inputs/disks_2d.toml"):
        assert "bond plasticity" not in validate_report(load_scene(scene))

"""SPB-MPM scene keys and pay-for-use: one-line errors for bad input, nothing PD allocated
before the first conversion, and what eq. 6.10 adds to an MPM step (counted, not timed)."""

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.errors import SceneError
from hpcmpm.parallel import Communicator
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

SCENE = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 1.0] }}
dx = 0.05
transfer = "{transfer}"
end_time = 0.01
[[materials]]
name = "m"
type = "{type}"
density = 1.0
{params}
{failure}
[[bodies]]
material = "m"
shape = "box"
lower = [0.3, 0.3]
upper = [0.7, 0.7]
velocity = [0.1, 0.0]
"""
ELASTIC = "E = 100.0\nnu = 0.3"
SPB = 'failure = { model = "spb", grid_energy = 1.0e6, bond_energy = 1.0 }'


def scene(type="fixed_corotated", params=ELASTIC, failure=SPB, transfer="mls"):
    return parse_scene(SCENE.format(type=type, params=params, failure=failure,
                                    transfer=transfer), "s.toml")


def problems(**kw):
    with pytest.raises(SceneError) as err:
        sim = Simulation(scene(**kw), make_domain(scene(**kw), Communicator()))
        del sim
    return str(err.value).splitlines()


def test_failure_on_a_material_without_a_stress_for_pd():
    lines = problems(type="weakly_compressible", params="E = 100.0")
    assert len(lines) == 1
    assert "materials[0].failure: material type 'weakly_compressible' has no stress for " \
           "peridynamics" in lines[0]


@pytest.mark.parametrize("failure,expect", [
    ('failure = { model = "spb", grid_energy = 0.0, bond_energy = 1.0 }',
     "materials[0].failure.grid_energy: must be > 0, got 0"),
    ('failure = { model = "spb", grid_energy = -2.0, bond_energy = 1.0 }',
     "materials[0].failure.grid_energy: must be > 0, got -2"),
    ('failure = { model = "spb", grid_energy = 1.0, bond_energy = 0.0 }',
     "materials[0].failure.bond_energy: must be > 0, got 0"),
    ('failure = { model = "spb", grid_energy = 1.0, bond_energy = 1.0, coupling = "both" }',
     "materials[0].failure.coupling: unknown value 'both'"),
    ('failure = { model = "eigen", grid_energy = 1.0, bond_energy = 1.0 }',
     "materials[0].failure.model: unknown value 'eigen'"),
])
def test_bad_failure_keys(failure, expect):
    lines = problems(failure=failure)
    assert len(lines) == 1 and expect in lines[0]


def test_spb_needs_mls():
    lines = problems(transfer="apic")
    assert len(lines) == 1 and "simulation.transfer = 'mls'" in lines[0]


def test_stretch_failure_needs_a_critical_stretch():
    lines = problems(failure='failure = { model = "spb", grid_energy = 1.0, bond_energy = 1.0, '
                             'bond_failure = "stretch" }')
    assert len(lines) == 1 and "failure.critical_stretch: missing" in lines[0]


SPB_TABLE = {"model": "spb", "grid_energy": 1.0, "bond_energy": 1.0}


def spb_material(type_="fixed_corotated", name="m", params=None, **failure):
    from hpcmpm.materials import make_material
    from hpcmpm.scene import MaterialSpec

    params = {"E": 100.0, "nu": 0.3} if params is None else params
    return make_material(MaterialSpec(name, type_, 1.0, {**params, "failure": {
        **SPB_TABLE, **failure}}), 2)


@pytest.mark.parametrize("key,a,b", [
    ("coupling", "exclusive", "additive"), ("bond_failure", "energy", "work"),
    ("critical_stretch", 0.01, 0.02), ("influence", "constant", "linear"),
    ("horizon", 3.015, 4.0), ("max_bond_stretch", 1.0, 0.5), ("clamp", "sticky_walls", "none")])
def test_spb_materials_must_agree_on_the_shared_keys(key, a, b):
    """The scene's one SPB extension reads these keys from the first SPB material only
    (hpcmpm/pd/spb.py: one bond set, one coupling, one clamp), so two SPB materials that
    differ in one of them are one problem naming that key; agreeing materials are none."""
    from hpcmpm.materials.failure import failure_scene_problems

    extra = {"bond_failure": "stretch"} if key == "critical_stretch" else {}
    same = [spb_material(name=n, **extra, **{key: a}) for n in "mn"]
    assert failure_scene_problems(same, "mls", "explicit") == []
    differ = [spb_material(name="m", **extra, **{key: a}),
              spb_material(name="n", **extra, **{key: b})]
    (problem,) = failure_scene_problems(differ, "mls", "explicit")
    assert problem[0] == f"materials[0].failure.{key}" and "must agree" in problem[1]


def test_pd_moduli_are_the_bulk_and_shear_moduli():
    """The PD micromoduli (stabilization, PD time step) take (bulk, shear) from the material:
    from E and nu the 2D plane-strain bulk modulus lam + mu = E / (2 (1 + nu)(1 - 2 nu)) and
    mu = E / (2 (1 + nu)) (3D: E / (3 (1 - 2 nu))); from an EOS, rho0 c0^2 and the shear
    modulus of the strength model. The same formulas in another order: a few ulps, 1e-15."""
    from hpcmpm.materials.failure import pd_moduli

    E, nu = 100.0, 0.3
    mat = spb_material()
    assert pd_moduli(2, mat) == pytest.approx((E / (2 * (1 + nu) * (1 - 2 * nu)),
                                               E / (2 * (1 + nu))), rel=1e-15)
    assert pd_moduli(3, mat)[0] == pytest.approx(E / (3 * (1 - 2 * nu)), rel=1e-15)
    shock = spb_material("shock", params={"E": 2e9, "nu": 0.3, "eos": {
        "type": "mie_gruneisen", "c0": 3940.0}})
    assert pd_moduli(2, shock) == pytest.approx((1.0 * 3940.0 ** 2, 2e9 / 2.6), rel=1e-15)


def run(sc):
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=sc.end_time, quiet=True)).run()
    return sim


def test_a_scene_that_never_converts_allocates_nothing_pd():
    """G_EE far above any stress: after the run no bonds, no PD halo, no re-transfer grid
    field, no PD phase; the only additions are the fields x0, EE, model, damage and one
    scalar grid field (the numerator of eq. 6.10)."""
    spb = run(scene())
    mpm = run(scene(failure=""))
    ext = spb.extensions[0]
    assert ext.pd_global == 0 and ext.bonds is None and ext.halo is None
    assert set(spb.grid.kinds) - set(mpm.grid.kinds) == {"spb_energy"}
    assert set(spb.particles.specs) - set(mpm.particles.specs) == {"x0", "EE", "model",
                                                                     "damage", "active_bonds"}
    assert not {"pd", "spb_retransfer"} & set(spb.timers.seconds)
    assert spb.particles["EE"].max() > 0.0
    assert np.all(spb.particles["model"] == 0)
    # Per particle and step eq. 6.10 adds one eigen-decomposition and a 9-node scalar
    # scatter (P2G scatters 3 fields to the same 9 nodes); per node, one more field in the
    # ghost sum and fill. Bytes per particle: x0 16 + EE 8 + model 1 + damage 8 +
    # active_bonds 4 = 37.
    extra = spb.particles.nbytes_per_particle() - mpm.particles.nbytes_per_particle()
    assert extra == 37


def test_3d_block_converts_and_keeps_its_momentum():
    """The 3D kernels (Jacobi tensile part, 3D re-transfer) on a small free block, every
    particle PD from the first step, a few steps: momentum to round-off, no NaN, bonds made."""
    text = """
[simulation]
dim = 3
domain = { lower = [0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }
dx = 0.1
transfer = "mls"
end_time = 0.01
[[materials]]
name = "m"
type = "fixed_corotated"
density = 1.0
E = 100.0
nu = 0.3
failure = { model = "spb", grid_energy = 1.0, bond_energy = 0.01, bond_failure = "work" }
[[bodies]]
material = "m"
shape = "box"
lower = [0.3, 0.3, 0.3]
upper = [0.7, 0.7, 0.7]
velocity = [0.2, 0.0, -0.1]
angular_velocity = [0.0, 3.0, 1.0]
"""
    sc = parse_scene(text, "b.toml")
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    sim.extensions[0].convert_all = True
    p = sim.particles
    p0 = (p["mass"][:, None] * p["v"]).sum(axis=0)
    scale = (p["mass"] * np.linalg.norm(p["v"], axis=1)).sum()
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=0.01, quiet=True)).run()
    ext = sim.extensions[0]
    assert ext.pd_global == p.n and ext.bonds.n_bonds > 50 * p.n
    assert np.isfinite(p["x"]).all() and np.isfinite(p["F"]).all()
    drift = np.abs((p["mass"][:, None] * p["v"]).sum(axis=0) - p0).max() / scale
    assert drift < 1e-13


def test_bond_damage_weighs_bonds_by_their_partial_volume():
    """003 eq. 4.8 with partial volumes: damage = 1 - sum_intact w / sum_all w, not the
    fraction of bonds broken (1/3 here), and a particle without bonds is undamaged."""
    from hpcmpm.pd.spb import bond_damage

    offsets = np.array([0, 3, 3])                # particle 1 has no bonds yet
    status = np.array([1, 0, 1], dtype=np.int8)
    weight = np.array([1.0, 0.5, 0.25])
    damage = np.full(4, -1.0)
    active = np.full(4, -1, dtype=np.int64)
    bond_damage(offsets, status, weight, 2, damage, active, np.array([2, 0]))
    assert damage[2] == pytest.approx(0.5 / 1.75, rel=1e-15) and active[2] == 2
    assert damage[0] == 0.0 and active[0] == 0
    assert damage[1] == -1.0 and damage[3] == -1.0   # only the rows named are written

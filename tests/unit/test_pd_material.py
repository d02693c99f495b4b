"""The peridynamic material in scenes: bad input gives one line naming the key, and a scene
without PD pays nothing for it."""

import math

import numpy as np
import pytest

from hpcmpm import cli

from hpcmpm.errors import SceneError
from hpcmpm.pd.clamp import near_rows
from hpcmpm.runner import make_domain
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.simulation import Simulation

PLATE = open("inputs/pd_plate_tear_2d.toml").read()


def sim_with(old: str, new: str) -> Simulation:
    assert old in PLATE
    scene = parse_scene(PLATE.replace(old, new), path="plate.toml")
    return Simulation(scene, make_domain(scene))


@pytest.mark.parametrize("old,new,line", [
    ("nu = 0.25 ", "nu = 0.3 ",
     "materials[0].nu: a PMB solid in 2D plane strain has nu = 0.25, got 0.3"),
    ('model = "pmb"', 'model = "pmb"\nplane = "stress"',
     "materials[0].nu: a PMB solid in 2D plane stress has nu = 0.333333, got 0.25"),
    ("fracture_energy = 10.0", "fracture_energy = 0.0",
     "materials[0].fracture_energy: must be > 0, got 0"),
    ("fracture_energy = 10.0", "fracture_energy = -2.0",
     "materials[0].fracture_energy: must be > 0, got -2"),
    ('model = "pmb"', 'model = "pmb"\nhorizon = 0.5',
     "materials[0].horizon: must be >= 1, got 0.5"),
    ('model = "pmb"', 'model = "pmb"\nhorizon_length = 0.001',
     "materials[0].horizon_length: 0.001 is below one particle spacing 0.01 "
     "(simulation.dx / particles_per_cell)"),
    # A typo of 3.0: `hpcmpm validate` ran out of memory building its lattice (and at 200
    # spacings in 3D took 3.6 minutes to say the scene needs 1.4 TiB). pi (m + 1/2)^2
    # half-bonds, the continuum count (m = 3000: 2.8e7).
    ('model = "pmb"', 'model = "pmb"\nhorizon = 3e3',
     "materials[0].horizon: 3000 particle spacings is more than 256: a complete family "
     "would hold about 2.8e+07 half-bonds per particle"),
    ('model = "pmb"', 'model = "pmb"\nhorizon_length = 1e9',
     "materials[0].horizon_length: 1e+11 particle spacings is more than 256"),
    ("[[0.5, 0.7], [0.5, 0.6]]", "[[0.5, 1.7], [0.5, 0.6]]",
     "materials[0].precracks[0]: outside the domain (lower [0, 0], upper [1, 1])"),
    ("[[0.5, 0.7], [0.5, 0.6]]", "[[0.5, 0.7, 0.1], [0.5, 0.6, 0.1]]",
     "materials[0].precracks[0]: must be a segment of two points [x, y]"),
    ('model = "pmb"', 'model = "correspondence"',
     "materials[0].stress_material: missing (the correspondence model evaluates another "
     "material's stress)"),
    ('model = "pmb"', 'model = "correspondence"\nstress_material = "steel"',
     "materials[0].stress_material: no material named 'steel' (have: glass)"),
    ('integration = "pd"', 'integration = "implicit"',
     "materials[0].integration: unknown value 'implicit'"),
    ('model = "pmb"', 'model = "pmb"\npartial_volumes = 1',
     "materials[0].partial_volumes: must be true or false, got 1"),
    ('model = "pmb"', 'model = "pmb"\nclamp = "sticky_walls"',
     "materials[0].clamp: 'sticky_walls' needs integration = 'grid' (off the grid the walls "
     "act on each particle; this body: integration = 'pd'); use 'auto' or 'none'"),
    ('model = "pmb"', 'model = "pmb"\nclamp = "yes"',
     "materials[0].clamp: unknown value 'yes'"),
])
def test_bad_input_is_one_line_with_exit_2(tmp_path, capsys, old, new, line):
    """Through the CLI (`hpcmpm validate`): one line in the scene file's format, exit 2."""
    assert old in PLATE
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.replace(old, new))
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"hpcmpm: error: {path}: {line}")


@pytest.mark.parametrize("old,new,lines", [
    # A pre-crack outside the domain (a check against the whole scene) and a misspelt output
    # field (checked with the materials configured against the scene): both at once.
    ("[[0.5, 0.7], [0.5, 0.6]]", "[[0.5, 1.7], [0.5, 0.6]]",
     ["materials[0].precracks[0]: outside the domain",
      "output.fields[0]: no particle field 'damag' in this scene (did you mean 'damage'?"]),
    # A correspondence model without its stress material cannot be configured: that line
    # alone, no traceback (the output fields are not checked against a material that
    # cannot be made).
    ('model = "pmb"', 'model = "correspondence"',
     ["materials[0].stress_material: missing"]),
])
def test_scene_problems_and_output_fields_are_reported_together(tmp_path, capsys, old, new,
                                                                 lines):
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.replace(old, new).replace('fields = ["damage"]',
                                                    'fields = ["damag"]'))
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == len(lines)
    for got, want in zip(err, lines):
        assert got.startswith(f"hpcmpm: error: {path}: {want}")


def test_pmb_in_3d_names_its_poisson_ratio(tmp_path, capsys):
    path = tmp_path / "cube.toml"
    path.write_text("""
[simulation]
dim = 3
domain = { lower = [0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }
dx = 0.1
end_time = 1.0

[[materials]]
name = "glass"
type = "peridynamic"
density = 2500.0
E = 7.2e10
nu = 0.3

[[bodies]]
material = "glass"
shape = "box"
lower = [0.4, 0.4, 0.4]
upper = [0.6, 0.6, 0.6]
""")
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"hpcmpm: error: {path}: materials[0].nu: a PMB solid in 3D has "
                   "nu = 0.25, got 0.3"]


def test_too_many_bonds_are_refused_at_the_scene_level_with_the_number(tmp_path, capsys):
    """A 250-spacing horizon (below the limit of 256): 197,156 half-bonds per interior
    particle (lattice points within 250.5 spacings, counted here), 22 B resident each
    (pd/bonds.py) plus 4 B of search scratch, times 1600 particles (7.6 GiB); `hpcmpm
    validate` prints that estimate, and `hpcmpm run` refuses it in one line before sampling
    when it exceeds the memory available (patched to 4 GiB here)."""
    ii, jj = np.meshgrid(np.arange(-251, 252), np.arange(-251, 252))
    count = int(np.sum(ii * ii + jj * jj < 250.5 ** 2)) - 1
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.replace('model = "pmb"', 'model = "pmb"\nhorizon = 250.0'))
    assert cli.main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    bonds = 1600 * count * (22 + 4) / 2**30
    assert f"{bonds:.1f} GiB for {count} half-bonds per particle of 'glass'" in out
    from hpcmpm import startup
    old = startup.available_memory
    startup.available_memory = lambda: 4 * 2**30
    try:
        assert cli.main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 2
    finally:
        startup.available_memory = old
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"hpcmpm: error: {path}: materials[0].horizon: the scene needs 1,600 particles")
    assert f"{count} half-bonds per particle" in err[0] and "lower materials[0].horizon" in err[0]


def test_particles_without_bonds_are_a_warning_with_their_count(tmp_path, caplog):
    """Two lone particles 5 spacings from anything (horizon 3.015 spacings): the run warns
    once, in the scene file's format, with the count, and goes on."""
    lone = "\n".join(f"""
[[bodies]]
name = "lone{k}"
material = "glass"
shape = "box"
lower = [{x}, 0.1]
upper = [{x + 0.01}, 0.11]
""" for k, x in enumerate((0.1, 0.15)))
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.replace("[walls]", lone + "\n[walls]"))
    with caplog.at_level("WARNING"):
        assert cli.main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet",
                         "--end-time", "1e-6"]) == 0
    warnings = [r.getMessage() for r in caplog.records if "no bond" in r.getMessage()]
    assert warnings == [f"{path}: materials[0]: warning: 2 particle(s) of material 'glass' "
                        "have no bond (horizon 0.03015, spacing 0.01): they move freely"]


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
    with pytest.raises(SceneError, match=r"plate.toml: materials\[0\].horizon: 36 half-bonds "
                       r"per particle need about"):
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


@pytest.mark.parametrize("scene, sets, states, ghost_states", [
    ("pd_plate_tear_2d", (), 0, 0),                               # PMB: no per-bond state
    ("ibmpm_wall_fracture_2d", (), 1, 1),     # plastic stretch; the floor clamp's ghosts
    ("ibmpm_wall_fracture_2d", ('materials.wall.clamp="none"',), 1, 0),
    ("ibmpm_wall_fracture_2d", ("materials.wall.plastic_yield=inf",), 0, 0),   # elastic
    ("ibmpm_wall_fracture_2d", ("materials.wall.plastic_yield=inf",
                                "materials.wall.plastic_yield_stretch=0.01"), 1, 1),
    ("ibmpm_cream_pie_2d", (), 3, 0),                   # the pie starts out of the wall's reach
    ("ibmpm_cream_pie_2d", ("bodies.0.center=[1.84, 0.6]",), 3, 5),       # clamped
    # memory = "none" stores no forces: the lengths only, on the bonds and in the store.
    ("ibmpm_cream_pie_2d", ('materials.cream.memory="none"',), 1, 0),
    ("ibmpm_cream_pie_2d", ('materials.cream.memory="none"', "bodies.0.center=[1.84, 0.6]"),
     1, 3),
])
def test_memory_estimate_counts_the_bond_states_a_run_allocates(scene, sets, states,
                                                                ghost_states):
    """The estimate before allocation (`side_bytes_per_particle`, used by the start-up
    memory check and the refusal above) prices a half-bond as the bonds the run then holds
    do, per-bond states included (22 B core, 8 B a state, 4 B search scratch), and the PD
    clamp's ghost store (clamp.ghost_store) for the particles within reach of a clamped
    wall only: one entry per half-bond and one for the particle's own image, each 22 B and
    8 B a state, for the share of the bodies' bounding boxes within reach. That share counts
    interior families, so it may exceed the store a run holds (fewer bonds near a body's
    edge, a disk's corners empty) but not fall below it by more than those (here: within
    a factor 2)."""
    from hpcmpm.runner import initial_particles

    sc = load_scene(f"inputs/{scene}.toml", list(sets))
    sim = Simulation(sc, make_domain(sc))
    initial_particles(sim)
    sim.ensure_grouped()
    ext = sim.extensions[0]
    ext.prepare()
    ext.model.dt = 1e-4                       # a rate model integrates over a step
    ext.compute_forces(*ext._rows())         # the models declare their state on first use
    material = ext.material
    n_bonds = material.half_bonds_per_particle()
    assert ext.bonds.resident_bytes_per_bond() == 22 + 8 * states
    if not ghost_states:
        assert ext.ghosts is None
        assert material.side_bytes_per_particle() == n_bonds * (22 + 8 * states + 4)
        return
    ghosts = ext.ghosts
    assert ghosts.resident_bytes_per_bond() == 22 + 8 * ghost_states
    # Entries exactly for the particles within reach, one per half-bond and one own.
    start, stop = ext._rows()
    near = near_rows(sim.particles["x0"][start:stop], stop - start, material.clamp_faces,
                     material.clamp_array())
    counts = ghosts.counts()
    assert 0 < near.sum() < len(near)
    assert np.array_equal(counts[near], ext.bonds.counts()[near] + 1)
    assert not counts[~near].any()
    estimate = material.side_bytes_per_particle() - n_bonds * (22 + 8 * states + 4)
    entries = len(near) * estimate / (22 + 8 * ghost_states)
    print(f"{scene}: {near.sum()} of {len(near)} particles in reach, ghost entries "
          f"{ghosts.n_bonds} (estimate {entries:.0f}); a dense store would hold "
          f"{ext.bonds.n_bonds} x {8 * ghost_states} B = "
          f"{ext.bonds.n_bonds * 8 * ghost_states / 1e6:.2f} MB, this one "
          f"{ghosts.nbytes() / 1e6:.2f} MB")
    assert ghosts.n_bonds <= entries < 2 * ghosts.n_bonds


def test_overlapping_bodies_of_one_pd_material_are_refused(tmp_path, capsys):
    """A second body over part of the plate samples the shared lattice points twice: bonds of
    no length, whose force is undefined. The run is refused in one line naming the count (it
    stopped at its first step as a numerical instability that advised a smaller step)."""
    patch = """
[[bodies]]
name = "patch"
material = "glass"
shape = "box"
lower = [0.35, 0.4]
upper = [0.4, 0.43]
"""
    path = tmp_path / "plate.toml"
    path.write_text(PLATE.replace("[walls]", patch + "\n[walls]"))
    assert cli.main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet",
                     "--end-time", "1e-6"]) == 2
    # 5 x 3 lattice points of spacing 0.01 inside the patch, which lies in the left half.
    assert capsys.readouterr().err.strip() == (
        f"hpcmpm: error: {path}: materials[0]: 15 particle(s) of material 'glass' lie where "
        f"another of its particles lies (bodies that overlap): a peridynamic bond needs two "
        f"distinct places; make its bodies disjoint or merge them into one")


@pytest.mark.parametrize("key,value", [("horizon_length", 1.0), ("horizon", 100.0)])
def test_a_family_reaching_across_a_periodic_axis_is_refused(tmp_path, capsys, key, value):
    """Periodic x of period 1: a family radius (horizon plus half a spacing, 0.005) of 1.005
    holds the particle's own image, a bond of zero reference length (one line, exit 2); a
    radius of 0.995 is accepted (tests/verification/test_pd_ibmpm_bar.py runs PD bars with
    radii between half the period and the period)."""
    periodic = PLATE.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = ["x"]')
    path = tmp_path / "plate.toml"
    path.write_text(periodic.replace('model = "pmb"', f'model = "pmb"\n{key} = {value}'))
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"hpcmpm: error: {path}: materials[0].{key}: the family radius 1.005 "
                   "reaches across the period 1 of the periodic axis x: a particle would bond "
                   "to its own image (the domain must be wider than 1.005 along x, or the "
                   "horizon shorter)"]
    path.write_text(periodic.replace('model = "pmb"', 'model = "pmb"\nhorizon_length = 0.99'))
    assert cli.main(["validate", str(path)]) == 0

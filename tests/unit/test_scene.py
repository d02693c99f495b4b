"""Scene validation: each kind of mistake gives its own line naming the file and the TOML key;
every problem in a file is reported at once; --set overrides; the resolved text round-trips."""

import math
from pathlib import Path

import pytest

from hpcmpm.errors import SceneError
from hpcmpm.materials import MATERIALS
from hpcmpm.scene import (BodySpec, ColliderSpec, MaterialSpec, PrescribedSpec, Scene, WallFace,
                          load_scene, parse_scene)

GOOD = Path("inputs/disks_2d.toml").read_text()
GOOD_3D = Path("inputs/snow_block_3d.toml").read_text()
SPHERE_0 = 'shape = "sphere"\ncenter = [0.25, 0.25]\nradius = 0.2'


def problems(text, overrides=()):
    with pytest.raises(SceneError) as info:
        parse_scene(text, "scene.toml", overrides)
    return info.value.problems


# One edit of a valid scene each, and the line it must produce (exactly).
CASES = {
    "unknown_key": (GOOD.replace("cfl = 0.4", "cfll = 0.4"),
                    "simulation.cfll: unknown key (did you mean 'cfl'?)"),
    "unknown_top_level": ("[outptu]\nevery = 1.0\n" + GOOD,
                          "outptu: unknown key (did you mean 'output'?)"),
    "unknown_material_param": (GOOD.replace("nu = 0.3", "nu = 0.3\nEE = 1.0"),
                               "materials[0].EE: unknown key (did you mean 'E'?)"),
    "wrong_type": (GOOD.replace("dx = 0.02", 'dx = "abc"'),
                   "simulation.dx: must be a number, got string 'abc'"),
    "wrong_type_material": (GOOD.replace("E = 1000.0", 'E = "abc"'),
                            "materials[0].E: must be a number, got string 'abc'"),
    "wrong_type_dim": (GOOD.replace("dim = 2", 'dim = "2"'),
                       "simulation.dim: must be the integer 2 or 3, got string '2'"),
    "missing_end_time": (GOOD.replace("end_time = 3.0", ""), "simulation.end_time: missing"),
    "missing_material_E": (GOOD.replace("E = 1000.0", ""), "materials[0].E: missing"),
    "nu_half": (GOOD.replace("nu = 0.3", "nu = 0.5"), "materials[0].nu: must be < 0.5, got 0.5"),
    "nu_minus_one": (GOOD.replace("nu = 0.3", "nu = -1.0"),
                     "materials[0].nu: must be > -1, got -1"),
    "density": (GOOD.replace("density = 1000.0", "density = 0.0"),
                "materials[0].density: must be > 0.0, got 0.0"),
    "E": (GOOD.replace("E = 1000.0", "E = -5.0"), "materials[0].E: must be > 0, got -5"),
    "dx": (GOOD.replace("dx = 0.02", "dx = -0.02"), "simulation.dx: must be > 0.0, got -0.02"),
    "dx_not_dividing": (GOOD.replace("dx = 0.02", "dx = 0.03"),
                        "simulation.dx: must divide the domain size evenly"),
    "cfl_zero": (GOOD.replace("cfl = 0.4", "cfl = 0.0"), "simulation.cfl: must be > 0.0, got 0.0"),
    "cfl_above_two": (GOOD.replace("cfl = 0.4", "cfl = 2.5"),
                      "simulation.cfl: must be <= 2.0, got 2.5"),
    "end_time": (GOOD.replace("end_time = 3.0", "end_time = 0.0"),
                 "simulation.end_time: must be > 0.0, got 0.0"),
    "domain_upper": (GOOD.replace("upper = [1.0, 1.0]", "upper = [1.0, 0.0]"),
                     "simulation.domain.upper: must exceed domain.lower in every component"),
    "particles_per_cell": (GOOD.replace("particles_per_cell = 2", "particles_per_cell = 0"),
                           "simulation.particles_per_cell: must be >= 1, got 0"),
    "particles_per_cell_float": (GOOD.replace("particles_per_cell = 2",
                                              "particles_per_cell = 2.5"),
                                 "simulation.particles_per_cell: must be an integer, got float"),
    "vector_components": (GOOD.replace("velocity = [0.1, 0.1]", "velocity = [0.1, 0.1, 0.0]"),
                          "bodies[0].velocity: must have 2 components (dim = 2), got 3"),
    "gravity_components": (GOOD.replace("end_time = 3.0", "end_time = 3.0\ngravity = [0.0]"),
                           "simulation.gravity: must have 2 components (dim = 2), got 1"),
    "body_outside": (GOOD.replace("center = [0.25, 0.25]", "center = [0.1, 0.25]"),
                     "bodies[0]: body lies outside the domain: its bounds [-0.1, 0.05]..[0.3, "
                     "0.45] exceed the domain [0, 0]..[1, 1]"),
    "unknown_body_material": (GOOD.replace('material = "rubber"', 'material = "rubbr"', 1),
                              "bodies[0].material: unknown material 'rubbr' (defined: rubber)"),
    "unknown_kernel": (GOOD.replace('kernel = "quadratic"', 'kernel = "quintic"'),
                       "simulation.kernel: unknown value 'quintic' (did you mean 'quadratic'? "
                       "valid: quadratic, cubic)"),
    "unknown_transfer": (GOOD.replace('transfer = "mls"', 'transfer = "apik"'),
                         "simulation.transfer: unknown value 'apik' (did you mean 'apic'? "
                         "valid: pic, flip, apic, mls)"),
    "unknown_volume_averaging": (GOOD.replace("[simulation]",
                                              '[simulation]\nvolume_averaging = "increments"'),
                                 "simulation.volume_averaging: unknown value 'increments' (did "
                                 "you mean 'increment'? valid: none, increment)"),
    # disks_2d's material is neo-Hookean: it carries F, no J to average.
    "volume_averaging_without_J": (GOOD.replace("[simulation]",
                                                '[simulation]\nvolume_averaging = "increment"'),
                                   "simulation.volume_averaging: 'increment' averages the "
                                   "stored J of oldroyd_b, herschel_bulkley, von_mises and "
                                   "weakly_compressible (unless it carries F, beside an "
                                   "F-based material with the explicit integrator); no "
                                   "material of this scene carries one"),
    "unknown_material_type": (GOOD.replace('type = "neo_hookean"', 'type = "neo_hooke"'),
                              "materials[0].type: unknown value 'neo_hooke' (did you mean "
                              f"'neo_hookean'? valid: {', '.join(sorted(MATERIALS))})"),
    "unknown_shape": (GOOD.replace('shape = "sphere"', 'shape = "spher"', 1),
                      "bodies[0].shape: unknown value 'spher' (did you mean 'sphere'? valid: "
                      "box, sphere, cylinder, mesh)"),
    "cylinder_in_2d": (GOOD.replace(SPHERE_0, 'shape = "cylinder"\ncenter = [0.25, 0.25]\n'
                                              'axis = [1.0, 0.0]\nradius = 0.1\nlength = 0.1'),
                       "bodies[0].shape: cylinder bodies need dim = 3 (in 2D use a box)"),
    "missing_mesh": (GOOD.replace(SPHERE_0, 'shape = "mesh"\nfile = "missing.stl"'),
                     "bodies[0].file: cannot read mesh"),
    "wall_condition": (GOOD + 'x_lower = { condition = "stick" }\n',
                       "walls.x_lower.condition: unknown value 'stick' (did you mean 'sticky'? "
                       "valid: sticky, slip, separate)"),
    "wall_face_3d_in_2d": (GOOD + 'z_lower = { condition = "sticky" }\n',
                           "walls.z_lower: unknown key"),
    "collider_radius": (GOOD + '[[colliders]]\nshape = "sphere"\ncenter = [0.5, 0.5]\n'
                               'radius = -1.0\n',
                        "colliders[0].radius: must be > 0.0, got -1.0"),
    "collider_normal": (GOOD + '[[colliders]]\nshape = "half_space"\npoint = [0.5, 0.1]\n'
                               'normal = [0.0, 0.0]\n',
                        "colliders[0].normal: must be a nonzero vector"),
    "prescribed_region": (GOOD + '[[prescribed]]\nregion = { lower = [0.5, 0.5], upper = '
                                 '[0.4, 0.6] }\n',
                          "prescribed[0].region.upper: must exceed region.lower in every "
                          "component"),
    "prescribed_missing_region": (GOOD + '[[prescribed]]\nname = "clamp"\n',
                                  "prescribed[0].region: missing (a table is required)"),
    "velocity_field_type": (GOOD.replace("velocity = [0.1, 0.1]", 'velocity_field = { type = '
                                         '"axial", amplitude = 1.0, length = 1.0 }', 1),
                            "bodies[0].velocity_field.type: unknown value 'axial'"),
    "output_field": (GOOD.replace("every = 0.1", 'every = 0.1\nfields = ["Jp"]'),
                     "output.fields[0]: no particle field 'Jp' in this scene (available: id, "
                     "group, x, v, mass, vol0, F, C, tau)"),
    "max_dt": (GOOD.replace("cfl = 0.4", "cfl = 0.4\nmax_dt = -1e-3"),
               "simulation.max_dt: must be > 0.0, got -0.001"),
    "checkpoint_every": (GOOD.replace("every = 0.1", "every = 0.1\ncheckpoint_every = 0"),
                         "output.checkpoint_every: must be >= 1, got 0"),
    "no_bodies": (GOOD[:GOOD.index("[[bodies]]")],
                  "bodies: missing: at least one [[bodies]] table is required"),
    "periodic_unknown_axis": (GOOD.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = ["z"]'),
                              "simulation.periodic: unknown axis 'z' (valid: x, y)"),
    "periodic_repeated_axis": (GOOD.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = ["y", "y"]'),
                               "simulation.periodic: axis 'y' named more than once"),
    "periodic_not_a_list": (GOOD.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = "x"'),
                            "simulation.periodic: must be an array of axis names"),
    "periodic_axis_with_a_wall": (GOOD.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = ["x"]')
                                  + 'x_upper = { condition = "sticky" }\n',
                                  "walls.x_upper: axis 'x' is periodic (simulation.periodic): "
                                  "its faces are not walls; remove walls.x_upper or the axis"),
    "unknown_key_without_a_close_match": (GOOD.replace("every = 0.1", "every = 0.1\nbogus = 1"),
                                          "output.bogus: unknown key (allowed: every, fields, "
                                          "checkpoint_every, checkpoint_keep)"),
    "dim_one": (GOOD.replace("dim = 2", "dim = 1"),
                "simulation.dim: must be the integer 2 or 3, got int 1"),
    # 2.0 == 2 passed the check and stopped the run with a TypeError traceback further on.
    "dim_float": (GOOD.replace("dim = 2", "dim = 2.0"),
                  "simulation.dim: must be the integer 2 or 3, got float 2.0"),
    "wrong_type_bool": (GOOD.replace("cfl = 0.4", "cfl = true"),
                        "simulation.cfl: must be a number, got boolean true"),
    "bool_in_vector": (GOOD.replace("velocity = [0.1, 0.1]", "velocity = [true, 0.1]"),
                       "bodies[0].velocity: must be an array of 2 numbers, got an array"),
    "vector_not_finite": (GOOD.replace("velocity = [0.1, 0.1]", "velocity = [nan, 0.1]"),
                          "bodies[0].velocity: must be finite, got [nan, 0.1]"),
    "density_infinite": (GOOD.replace("density = 1000.0", "density = inf"),
                         "materials[0].density: must be finite, got inf"),
    "material_param_bool": (GOOD.replace("E = 1000.0", "E = true"),
                            "materials[0].E: must be a number, got boolean true"),
    # A quoted number is a string, as for the scene's own keys (it was read as 1000).
    "material_param_quoted_number": (GOOD.replace("E = 1000.0", 'E = "1000"'),
                                     "materials[0].E: must be a number, got string '1000'"),
    "material_param_infinite": (GOOD.replace("E = 1000.0", "E = inf"),
                                "materials[0].E: must be finite, got inf"),
    "material_param_nan": (GOOD.replace("E = 1000.0", "E = nan"),
                           "materials[0].E: must be a number, got float nan"),
    # An integer beyond a float64 (tomllib reads any size) was an OverflowError traceback.
    "integer_too_large": (GOOD.replace("E = 1000.0", "E = 1" + "0" * 400),
                          "materials[0].E: integer too large (beyond the range of a float64)"),
    # A combination the model's constructor refuses is told at its [[materials]] entry.
    "material_refused_by_its_model": (GOOD.replace('type = "neo_hookean"', 'type = "j2"').replace(
        "nu = 0.3", 'nu = 0.3\nspecific_heat = 400.0\nhardening = { type = "johnson_cook", '
                    "A = 1.0, T_melt = 200.0 }"),
        "materials[0]: material 'rubber' (j2): hardening.T_melt: must be > T_room = 293, "
        "got 200"),
    # A run without an end needs a frame interval: the default (end_time) gave t = 0 only.
    "end_time_inf_without_every": (GOOD.replace("end_time = 3.0", "end_time = inf")
                                   .replace("every = 0.1", ""),
                                   "output.every: required when simulation.end_time is inf (a "
                                   "run that ends only when stopped): its default, end_time, "
                                   "would give the frame at t = 0 alone"),
    "dt_negative": (GOOD.replace("cfl = 0.4", "cfl = 0.4\ndt = -0.01"),
                    "simulation.dt: must be > 0.0, got -0.01"),
    # An infinite fixed step passed validation and blew up at the first step (exit 3).
    "dt_infinite": (GOOD.replace("cfl = 0.4", "cfl = 0.4\ndt = inf"),
                    "simulation.dt: must be finite, got inf"),
    "periodic_axis_with_a_lower_wall": (GOOD.replace("cfl = 0.4", 'cfl = 0.4\nperiodic = ["y"]')
                                        + 'y_lower = { condition = "slip" }\n',
                                        "walls.y_lower: axis 'y' is periodic (simulation."
                                        "periodic): its faces are not walls; remove "
                                        "walls.y_lower or the axis"),
    "periodic_not_names": (GOOD.replace("cfl = 0.4", "cfl = 0.4\nperiodic = [0]"),
                           "simulation.periodic: must be an array of axis names, got an array"),
    "checkpoint_keep": (GOOD.replace("every = 0.1", "every = 0.1\ncheckpoint_keep = 0"),
                        "output.checkpoint_keep: must be >= 1, got 0"),
    "rebalance_threshold": (GOOD + "[parallel]\nrebalance_threshold = 1.0\n",
                            "parallel.rebalance_threshold: must be > 1.0, got 1.0"),
    "solver_tolerance_one": (GOOD + "[solver]\ntolerance = 1.0\n",
                             "solver.tolerance: must be < 1.0, got 1.0"),
    "solver_max_iterations_float": (GOOD + "[solver]\nmax_iterations = 100.5\n",
                                    "solver.max_iterations: must be an integer, got float 100.5"),
    "solver_newton_stop": (GOOD + '[solver]\nnewton_stop = "relative"\n',
                           "solver.newton_stop: unknown value 'relative' (valid: momentum, "
                           "galilean)"),
    "duplicate_material": (GOOD.replace("[[bodies]]", '[[materials]]\nname = "rubber"\ntype = '
                                        '"neo_hookean"\ndensity = 1.0\nE = 1.0\nnu = 0.3\n\n'
                                        "[[bodies]]", 1),
                           "materials[1].name: duplicate material name 'rubber'"),
    "box_flat": (GOOD.replace(SPHERE_0, 'shape = "box"\nlower = [0.1, 0.1]\nupper = [0.4, 0.1]'),
                 "bodies[0].upper: must exceed lower in every component"),
    "sphere_radius": (GOOD.replace("radius = 0.2", "radius = -0.2", 1),
                      "bodies[0].radius: must be > 0.0, got -0.2"),
    "velocity_field_axis": (GOOD.replace("velocity = [0.1, 0.1]", 'velocity_field = { type = '
                                         '"axial_mode", amplitude = 1.0, length = 1.0, '
                                         "axis = 2 }"),
                            "bodies[0].velocity_field.axis: must be <= 1, got 2"),
    "jitter_above_one": (GOOD.replace("velocity = [0.1, 0.1]", "jitter = 1.5"),
                         "bodies[0].jitter: must be <= 1.0, got 1.5"),
    # numpy's generator refuses a negative seed: it was a traceback when the body was sampled.
    "seed_negative": (GOOD.replace("velocity = [0.1, 0.1]", "jitter = 0.1\nseed = -1"),
                      "bodies[0].seed: must be >= 0, got -1"),
    "walls_friction": (GOOD + "friction = -0.1\n", "walls.friction: must be >= 0.0, got -0.1"),
    "wall_face_friction": (GOOD + "x_lower = { friction = -0.1 }\n",
                           "walls.x_lower.friction: must be >= 0.0, got -0.1"),
    "collider_friction": (GOOD + '[[colliders]]\nshape = "sphere"\ncenter = [0.5, 0.5]\n'
                                 "radius = 0.1\nfriction = -0.5\n",
                          "colliders[0].friction: must be >= 0.0, got -0.5"),
    "collider_half_extents": (GOOD + '[[colliders]]\nshape = "box"\ncenter = [0.5, 0.5]\n'
                                     "half_extents = [0.1, 0.0]\n",
                              "colliders[0].half_extents: components must be > 0, got "
                              "[0.1, 0.0]"),
    "collider_start": (GOOD + '[[colliders]]\nshape = "sphere"\ncenter = [0.5, 0.5]\n'
                              "radius = 0.1\nstart = -1.0\n",
                       "colliders[0].start: must be >= 0.0, got -1.0"),
    # A collider whose window ends before it starts never acts: it was accepted silently.
    "collider_end_before_start": (GOOD + '[[colliders]]\nshape = "sphere"\ncenter = [0.5, 0.5]'
                                         "\nradius = 0.1\nstart = 2.0\nend = 1.0\n",
                                  "colliders[0].end: must be >= start (2), got 1"),
    "cylinder_collider_in_2d": (GOOD + '[[colliders]]\nshape = "cylinder"\ncenter = [0.5, 0.5]'
                                       "\naxis = [1.0, 0.0]\nradius = 0.1\nhalf_length = 0.1\n",
                                "colliders[0].shape: cylinder colliders need dim = 3"),
    "prescribed_flat_region": (GOOD + "[[prescribed]]\nregion = { lower = [0.5, 0.5], upper = "
                                      "[0.6, 0.5] }\n",
                               "prescribed[0].region.upper: must exceed region.lower in every "
                               "component"),
    # A size may not be infinite (its bounds were NaN: "body lies outside the domain").
    "infinite_radius": (GOOD.replace("radius = 0.2", "radius = inf", 1),
                        "bodies[0].radius: must be finite, got inf"),
    # A frame every 1e-5 to t = 3: 3e5 files, and the steps shortened to land on each.
    "too_many_frames": (GOOD.replace("every = 0.1", "every = 1e-5"),
                        "output.every: 1e-05 would write 3e+05 frames to t = 3, a file each "
                        "(at most 100000): raise output.every"),
    # The line of "dim = 2" in the scene file (its header may grow), 1-based as TOML counts.
    "toml_syntax": (GOOD.replace("dim = 2", "dim = = 2"),
                    "TOML syntax error: Invalid value (at line "
                    f"{GOOD.splitlines().index('dim = 2') + 1}, column 7)"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_mistake_gives_one_line_naming_file_and_key(case):
    text, expected = CASES[case]
    lines = problems(text)
    assert len(lines) == 1, lines
    assert lines[0].startswith("scene.toml: ") and expected in lines[0], lines[0]


def test_three_dimensional_mistakes():
    lines = problems(GOOD_3D.replace('shape = "sphere"', 'shape = "cylinder"')
                     .replace("radius = 0.12", "radius = 0.12\naxis = [0.0, 0.0, 0.0]\n"
                                               "half_length = 0.1"))
    assert lines == ["scene.toml: colliders[0].axis: must be a nonzero vector"]
    lines = problems(GOOD_3D.replace("angular_velocity", "x").replace(
        'velocity = [0.0, 0.0, -1.2]', 'velocity = [0.0, 0.0, -1.2]\nangular_velocity = 1.0'))
    assert lines == ["scene.toml: colliders[0].angular_velocity: must be an array of 3 "
                     "numbers, got float 1.0"]


def test_cylinder_body_needs_a_nonzero_axis():
    """A cylinder body with a zero axis is one line at its axis (its bounds would divide by
    the axis length)."""
    lines = problems(GOOD_3D.replace('shape = "box"\nlower = [0.3, 0.3, 0.0]\nupper = [0.7, 0.7, '
                                     '0.25]', 'shape = "cylinder"\ncenter = [0.5, 0.5, 0.2]\n'
                                              'axis = [0.0, 0.0, 0.0]\nradius = 0.1\n'
                                              'length = 0.2'))
    assert lines == ["scene.toml: bodies[0].axis: must be a nonzero vector"]


@pytest.mark.parametrize("scale", [1e-170, 1e-320, 1e200, 8e307])
def test_a_direction_of_any_representable_length_is_its_unit_vector(scale):
    """Axes and normals are directions: a cylinder's axis whose squared length underflows
    (1e-170) or overflows (1e200) is the same body as the unit axis, not a NaN one (it was
    reported outside the domain with NaN bounds, or sampled ignoring its length). Exact:
    the scaled vector is divided by its largest component first."""
    from hpcmpm.geometry import estimate_body_counts
    from hpcmpm.scene import body_bounds, load_scene

    base = ["bodies.bullet.axis=[2.0, 1.0, 0.0]"]
    odd = [f"bodies.bullet.axis=[{2 * scale!r}, {scale!r}, 0.0]"]
    unit, scaled = (load_scene("inputs/gelatin_bullet_3d.toml", o) for o in (base, odd))
    axis = scaled.bodies[1].params["axis"]
    assert axis == unit.bodies[1].params["axis"]
    assert math.isclose(math.hypot(*axis), 1.0, rel_tol=1e-15)
    assert body_bounds("cylinder", scaled.bodies[1].params, 3) == \
        body_bounds("cylinder", unit.bodies[1].params, 3)
    assert estimate_body_counts(scaled)[0] == estimate_body_counts(unit)[0]
    collider = GOOD_3D.replace('shape = "sphere"', 'shape = "cylinder"').replace(
        "radius = 0.12", f"radius = 0.12\naxis = [0.0, {scale!r}, {scale!r}]\nhalf_length = 0.1")
    assert parse_scene(collider, "scene.toml").colliders[0].params["axis"] == \
        (0.0, 1.0 / math.sqrt(2.0), 1.0 / math.sqrt(2.0))


def test_every_problem_in_a_file_is_reported_in_file_order():
    text = (GOOD.replace("cfl = 0.4", "cfl = -1.0").replace('kernel = "quadratic"', 'kernl = 1')
            .replace("nu = 0.3", "nu = 0.7").replace("center = [0.75, 0.75]", "center = [2, 2]"))
    lines = problems(text)
    assert [l.split(": ")[1] for l in lines] == [
        "simulation.kernl", "simulation.cfl", "materials[0].nu", "bodies[1]"], lines


def test_set_overrides_values_tables_and_list_items():
    scene = parse_scene(GOOD, "s.toml", ["simulation.cfl=0.3", "materials.0.E=1e5",
                                         'simulation.kernel="cubic"', "simulation.transfer=apic",
                                         "bodies.1.velocity=[0.0, -0.2]", "output.every=0.5",
                                         "walls.y_lower.condition=sticky"])
    assert scene.cfl == 0.3 and scene.kernel == "cubic" and scene.transfer == "apic"
    assert scene.materials[0].params["E"] == 1e5
    assert scene.bodies[1].velocity == (0.0, -0.2)
    assert scene.output.every == 0.5
    assert scene.walls.faces[2] == WallFace("sticky", 0.0)
    # The resolved text records the overrides, so a checkpoint restarts the same scene.
    assert parse_scene(scene.text) == scene


def test_bad_overrides_are_reported_like_file_problems():
    # A bad value that came from the command line says so: the file itself is fine.
    lines = problems(GOOD, ["simulation.cfl=abc", "materials.3.E=1", "nonsense",
                            "simulation.cfll=0.3", "materials.steel.E=1",
                            "materials.rubber.nu=0.7", "bodies.1.velocity=2"])
    assert lines == [
        "scene.toml: --set materials.3.E: no entry 3 (materials has 1)",
        "scene.toml: --set nonsense: expected key.path=value",
        "scene.toml: --set materials.steel.E: no entry named 'steel' in materials (names: "
        "rubber; or give an index)",
        "scene.toml: simulation.cfll: unknown key (did you mean 'cfl'?) "
        "(from --set simulation.cfll=0.3)",
        "scene.toml: simulation.cfl: must be a number, got string 'abc' "
        "(from --set simulation.cfl=abc)",
        "scene.toml: materials[0].nu: must be < 0.5, got 0.7 (from --set materials.rubber.nu=0.7)",
        "scene.toml: bodies[1].velocity: must be an array of 2 numbers, got int 2 "
        "(from --set bodies.1.velocity=2)",
    ]



def test_override_into_a_section_the_file_lacks_names_the_missing_entry():
    """``--set colliders.0.radius=0.1`` on a scene without [[colliders]]: the entry is missing
    (it said "colliders: must be an array of tables, got a table", a table made up by the
    override itself)."""
    assert "[[colliders]]" not in GOOD and "[[prescribed]]" not in GOOD
    assert problems(GOOD, ["colliders.0.radius=0.1", "prescribed.lid.velocity=[1, 0]"]) == [
        "scene.toml: --set colliders.0.radius: no entry 0 (colliders has 0)",
        "scene.toml: --set prescribed.lid.velocity: no entry named 'lid' (prescribed has 0)"]


def test_set_index_one_past_the_end_and_an_empty_key_are_reported():
    """``--set bodies.2...`` with two bodies names the count (not an IndexError), and
    ``--set =5`` has no key."""
    assert problems(GOOD, ["bodies.2.velocity=[0.0, 0.0]", "=5"]) == [
        "scene.toml: --set bodies.2.velocity: no entry 2 (bodies has 2)",
        "scene.toml: --set =5: expected key.path=value"]

def test_load_scene_reports_the_path_and_a_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("dx = 0.02", "dx = 0.0"))
    with pytest.raises(SceneError) as info:
        load_scene(bad)
    assert info.value.problems == [f"{bad}: simulation.dx: must be > 0.0, got 0.0"]
    with pytest.raises(SceneError, match="no/such.toml: no such file"):
        load_scene("no/such.toml")
    assert SceneError.exit_code == 2


def test_load_scene_reports_a_file_it_cannot_read(tmp_path):
    """A folder or a file that is not UTF-8 text is one "cannot read" line naming it, not a
    traceback."""
    binary = tmp_path / "scene.toml"
    binary.write_bytes(b"\xff\xfe\x00dim = 2")
    for path in (tmp_path, binary):
        with pytest.raises(SceneError) as info:
            load_scene(path)
        (line,) = info.value.problems
        assert line.startswith(f"{path}: cannot read: "), line


def test_a_scene_is_read_as_utf8_with_or_without_a_byte_order_mark(tmp_path):
    """TOML is UTF-8: a scene saved with a byte-order mark (Windows editors) is the same
    scene, not "TOML syntax error: Invalid statement (at line 1, column 1)"; and a shipped
    scene with a non-ASCII comment (10 of them cite sections as "§") loads under a locale
    whose encoding is ASCII (a cluster's LC_ALL without UTF-8), where it was "cannot read:
    'ascii' codec can't decode byte 0xc2"."""
    import os
    import subprocess
    import sys

    text = GOOD.replace('"lower_left"', '"Scheibe_ü"')
    plain, bom = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_bytes(text.encode("utf-8"))
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    a, b = load_scene(plain), load_scene(bom)
    assert a.text == b.text and a.bodies == b.bodies and a.materials == b.materials
    assert a.bodies[0].name == "Scheibe_ü"
    scene = "inputs/disks_2d.toml"
    assert "§" in Path(scene).read_text(encoding="utf-8")
    env = {**os.environ, "LC_ALL": "C.ISO-8859-1", "PYTHONUTF8": "0",
           "PYTHONIOENCODING": "utf-8"}
    code = (f"import locale; from hpcmpm.scene import load_scene; "
            f"print(locale.getpreferredencoding(False), load_scene({scene!r}).dim)")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    encoding, dim = out.stdout.split()
    assert encoding != "UTF-8" and dim == "2", out.stdout


def test_dataclasses_and_defaults():
    scene = parse_scene(GOOD, "s.toml")
    assert isinstance(scene, Scene)
    assert (scene.dim, scene.domain_lo, scene.domain_hi, scene.dx) == (2, (0.0, 0.0),
                                                                       (1.0, 1.0), 0.02)
    assert (scene.particles_per_cell, scene.kernel, scene.transfer) == (2, "quadratic", "mls")
    assert scene.dt is None and scene.max_dt is None and scene.gravity == (0.0, 0.0)
    assert scene.flip_alpha == 0.95 and scene.parallel.rebalance_threshold == 1.2
    assert scene.output.checkpoint_every is None and scene.output.checkpoint_keep == 2
    assert scene.materials == (MaterialSpec("rubber", "neo_hookean", 1000.0,
                                            {"E": 1000.0, "nu": 0.3}),)
    assert scene.bodies[0] == BodySpec("lower_left", "rubber", "sphere",
                                       {"center": (0.25, 0.25), "radius": 0.2}, (0.1, 0.1),
                                       0.0, 0.0, 0, None)
    assert scene.walls.faces == (WallFace("slip", 0.0),) * 4
    with pytest.raises(AttributeError):
        scene.dx = 1.0  # frozen
    snow = parse_scene(GOOD_3D, "s.toml")
    assert snow.colliders[0] == ColliderSpec("ball", "sphere", {"center": (0.5, 0.5, 0.45),
                                                                "radius": 0.12},
                                             "separate", 0.2, (0.0, 0.0, -1.2),
                                             (0.0, 0.0, 0.0), 0.0, math.inf)
    assert snow.walls.faces[4] == WallFace("sticky", 0.0)
    assert snow.walls.faces[5] == WallFace("slip", 0.0)
    sponge = load_scene("inputs/sponge_twist_3d.toml")
    assert sponge.prescribed[1] == PrescribedSpec(
        "right_clamp", {"lower": (0.75, 0.4, 0.4), "upper": (0.8, 0.6, 0.6)}, (0.0, 0.0, 0.0),
        (3.14159, 0.0, 0.0), (0.775, 0.5, 0.5))


def test_defaults_of_absent_keys():
    """The documented defaults (docs/scene-format.md) of the keys disks_2d.toml spells out:
    particles_per_cell 2, quadratic kernel, MLS, cfl 0.4, a frame every end_time, slip walls,
    the explicit integrator and the solver's settings."""
    text = GOOD
    for line in ("particles_per_cell = 2", 'kernel = "quadratic"', 'transfer = "mls"',
                 "cfl = 0.4", "every = 0.1", 'default = "slip"'):
        assert line in text
        text = text.replace(line + "\n", "")
    scene = parse_scene(text, "s.toml")
    assert (scene.particles_per_cell, scene.kernel, scene.transfer, scene.cfl) == (
        2, "quadratic", "mls", 0.4)
    assert scene.output.every == scene.end_time == 3.0
    assert scene.walls.faces == (WallFace("slip", 0.0),) * 4
    assert scene.integrator == "explicit"
    assert (scene.solver.mode, scene.solver.preconditioner, scene.solver.tolerance,
            scene.solver.max_iterations, scene.solver.newton_tolerance,
            scene.solver.newton_stop) == ("linearized", "jacobi", 1e-6, 1000, 1e-6, "momentum")
    assert (scene.parallel.rebalance_threshold, scene.parallel.rebalance_every) == (1.2, 20)


def test_closed_bounds_admit_their_end_values():
    """The documented closed ends are valid: cfl 2, flip_alpha 0 and 1, jitter 1, zero
    friction, one cell along an axis (dx = the domain extent), a collider acting at one instant
    (start = end)."""
    collider = ('[[colliders]]\nshape = "sphere"\ncenter = [0.5, 0.5]\nradius = 0.1\n'
                "friction = 0.0\nstart = 0.5\nend = 0.5\n")
    scene = parse_scene(GOOD.replace("cfl = 0.4", "cfl = 2.0\nflip_alpha = 1.0")
                        .replace("velocity = [0.1, 0.1]", "jitter = 1.0")
                        + "friction = 0.0\n" + collider, "s.toml")
    assert (scene.cfl, scene.flip_alpha, scene.bodies[0].jitter) == (2.0, 1.0, 1.0)
    assert scene.walls.faces[0].friction == 0.0
    assert (scene.colliders[0].start, scene.colliders[0].end) == (0.5, 0.5)
    assert parse_scene(GOOD.replace("cfl = 0.4", "flip_alpha = 0.0")).flip_alpha == 0.0
    one_cell = GOOD.replace("dx = 0.02", "dx = 1.0")
    assert parse_scene(one_cell).dx == 1.0

def test_periodic_axes_are_sorted_indices_and_default_to_none():
    assert parse_scene(GOOD).periodic == ()
    assert parse_scene(GOOD).volume_averaging == "none"
    scene = parse_scene(GOOD_3D.replace("[simulation]", '[simulation]\nperiodic = ["y", "x"]'))
    assert scene.periodic == (0, 1)
    assert parse_scene(scene.text) == scene  # the resolved text keeps the key


def test_wall_defaults_and_per_face_overrides():
    scene = parse_scene(GOOD.replace('default = "slip"', 'default = "separate"\nfriction = 0.2\n'
                                     'x_upper = { condition = "sticky" }\n'
                                     'y_lower = { friction = 0.5 }'), "s.toml")
    assert scene.walls.faces == (WallFace("separate", 0.2), WallFace("sticky", 0.2),
                                 WallFace("separate", 0.5), WallFace("separate", 0.2))


@pytest.mark.parametrize("scene_file", sorted(Path("inputs").glob("*.toml")), ids=str)
def test_inputs_validate_and_round_trip(scene_file):
    scene = load_scene(scene_file)
    assert scene.path == str(scene_file)
    again = parse_scene(scene.text)
    assert again == scene and again.text == scene.text
    assert scene.text.startswith("[simulation]") or "[simulation]" in scene.text


def test_round_trip_keeps_mesh_paths_absolute(tmp_path):
    import meshio
    import numpy as np

    pts = np.array([[0.2, 0.2, 0.0], [0.6, 0.2, 0.0], [0.2, 0.6, 0.0]])
    meshio.write(str(tmp_path / "t.vtk"), meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))]))
    scene_file = tmp_path / "s.toml"
    scene_file.write_text(GOOD.replace(SPHERE_0, 'shape = "mesh"\nfile = "t.vtk"'))
    scene = load_scene(scene_file)
    assert scene.bodies[0].params["bounds"] == ((0.2, 0.2), (0.6, 0.6))
    assert parse_scene(scene.text, "elsewhere/checkpoint.h5") == scene


def test_the_documented_example_is_a_valid_scene():
    import re

    doc = Path("docs/scene-format.md").read_text()
    example = re.search(r"```toml\n(.*?)```", doc, re.S).group(1)
    scene = parse_scene(example, "docs/scene-format.md")
    assert len(scene.bodies) == 2 and scene.colliders[0].end == 1.0
    assert scene.walls.faces[0] == WallFace("separate", 0.3)


def test_set_picks_array_entries_by_name_or_default_name():
    text = GOOD + """
[[colliders]]
shape = "half_space"
point = [0.0, 0.1]
normal = [0.0, 1.0]
"""
    scene = parse_scene(text, "scene.toml", ["materials.rubber.E=2000.0",
                                             "bodies.upper_right.velocity=[0.0, -0.2]",
                                             "colliders.collider0.friction=0.5"])
    assert scene.materials[0].params["E"] == 2000.0
    assert scene.bodies[1].name == "upper_right" and scene.bodies[1].velocity == (0.0, -0.2)
    assert scene.bodies[0].velocity == (0.1, 0.1)  # only the named body changed
    assert scene.colliders[0].friction == 0.5
    # By name and by index reach the same entry.
    assert parse_scene(GOOD, "s", ["bodies.lower_left.radius=0.1"]) == \
        parse_scene(GOOD, "s", ["bodies.0.radius=0.1"])


@pytest.mark.parametrize("path", sorted(Path("inputs").glob("*.toml")), ids=lambda p: p.stem)
def test_output_fields_offered_are_the_fields_the_run_allocates(path):
    """One source (simulation.particle_field_specs): the scene check offers exactly the fields a
    Simulation of the scene allocates, plus tau (computed for output)."""
    from hpcmpm.runner import make_domain
    from hpcmpm.simulation import Simulation

    with pytest.raises(SceneError) as info:
        load_scene(path, ['output.fields=["no_such_field"]'])
    offered = info.value.problems[0].split("available: ")[1].rstrip(")").split(", ")
    scene = load_scene(path)
    allocated = set(Simulation(scene, make_domain(scene)).particles.specs)
    assert set(offered) == allocated | {"tau"}, (offered, allocated)


def test_a_run_without_an_end_is_accepted_with_a_frame_interval():
    """`end_time = inf`: a run that ends when a signal stops it (SIGTERM/SIGUSR1 write a
    checkpoint), with its frames every output.every."""
    from hpcmpm.scene import parse_scene

    scene = parse_scene(GOOD.replace("end_time = 3.0", "end_time = inf"), path="s.toml")
    assert math.isinf(scene.end_time) and scene.output.every == 0.1


def test_unknown_material_is_reported_beside_a_bad_material():
    """Every problem at once (docs/scene-format.md, "Errors"): a body naming an undefined
    material is reported although another material has a problem of its own (it was held
    back until that one was fixed), and a body naming the bad material is not "unknown"."""
    lines = problems(GOOD, ["materials.rubber.nu=0.7", "bodies.1.material=rubbr"])
    assert "scene.toml: materials[0].nu: must be < 0.5, got 0.7 (from --set " \
        "materials.rubber.nu=0.7)" in lines
    assert "scene.toml: bodies[1].material: unknown material 'rubbr' (defined: rubber) " \
        "(from --set bodies.1.material=rubbr)" in lines
    assert not any("bodies[0].material" in line for line in lines), lines

"""A blow-up stops the run with step, time, particle ids, material and a hint (exit code 3);
the frames already written stay readable and hold no NaN."""

import re
import sys
from pathlib import Path

import h5py
import pytest
import numpy as np
from launch import run_in_group


def test_too_large_fixed_dt_stops_with_a_clear_message(tmp_path):
    exe = Path(sys.executable).with_name("hpcmpm")
    out = tmp_path / "out"
    # 50x the CFL bound of this scene: the explicit update is violently unstable.
    proc = run_in_group(
        [str(exe), "run", "inputs/disks_2d.toml", "--out", str(out), "--quiet",
         "--set", "simulation.dt=0.3", "--set", "output.every=0.6", "--end-time", "30",
         "--checkpoint-every", "1"],
        timeout=120)
    assert proc.returncode == 3, proc.stderr
    assert "Traceback" not in proc.stderr
    message = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
    assert len(message) == 1
    for part in ("numerical instability at step", "t=", "ids", "material 'rubber'",
                 "lower simulation.cfl"):
        assert part in message[0], message[0]
    assert "exceeds the CFL bound" in proc.stderr  # the fixed dt warned first
    frames = sorted(out.glob("frame_*.h5"))
    assert frames, "the frame at t = 0 was written before the blow-up"
    for frame in frames:
        with h5py.File(frame) as f:
            for name in ("x", "v", "F"):
                assert np.all(np.isfinite(f[f"particles/{name}"][...])), frame
    assert not list(out.glob("*.tmp"))
    # A checkpoint every step: none of the step that blew up (it was written, and a restart,
    # as a requeued job does from the newest, failed on it at once).
    broken = int(re.search(r"instability at step (\d+)", message[0]).group(1))
    steps = [int(p.stem.split("_")[1]) for p in out.glob("ckpt_*.h5")]
    assert steps and max(steps) == broken - 1, (steps, broken)


def test_an_initial_state_out_of_range_is_named_as_the_scene_s(tmp_path):
    """A body speed of 1e299 (its square overflows) and an axial mode of length 1e-310 (its
    sine is NaN) validate, and the first health check stops them before any step. The hint
    pointed at simulation.cfl, which cannot help there; it now names the initial state. The
    axial mode also printed two RuntimeWarnings (overflow in divide, invalid value in sin)
    before the line; the command line now logs them (`cli.floating_point_errors_logged`).
    The refusal comes before `--out` is made (it left an empty folder)."""
    exe = Path(sys.executable).with_name("hpcmpm")
    for scene, setting, material in (
            ("inputs/disks_2d.toml", "bodies.0.velocity=[1e299, 0.0]", "'rubber'"),
            ("inputs/bar_2d.toml", "bodies.0.velocity_field.length=1e-310", "'bar'")):
        out = tmp_path / Path(scene).stem
        proc = run_in_group([str(exe), "run", scene, "--out", str(out), "--quiet", "--set",
                             setting], timeout=120)
        assert proc.returncode == 3, proc.stderr
        assert proc.stderr.startswith("hpcmpm: error: numerical instability at step 0, t=0:")
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr  # no warnings
        assert f"material {material}" in proc.stderr
        assert "this is the initial state, before the first step" in proc.stderr
        assert "simulation.cfl" not in proc.stderr
        # Refused before the output folder is made: no empty folder is left behind.
        assert not out.exists()


def test_a_particle_far_outside_the_domain_is_broken():
    """`scan_health`: a finite particle more than the domain's size outside it is a blown-up
    state (its grid block would be enormous: a 374 GiB allocation failed with a MemoryError
    traceback); one just beyond a face (advected a little past a wall) is not, and NaN in x
    is broken as before."""
    from hpcmpm.kernels.particles import scan_health

    lo, hi = np.array([-1.0, -1.0]), np.array([2.0, 2.0])   # the unit domain, widened by 1
    x = np.array([[0.5, 0.5], [1.02, -0.01], [0.5, 2.5], [-1.5, 0.5], [1e5, 0.5],
                  [np.nan, 0.5], [2.0, -1.0]])
    v = np.ones_like(x)
    F = np.tile(np.eye(2), (len(x), 1, 1))
    bad = np.zeros(8, dtype=np.int64)
    speed, nbad = scan_health(x, v, F, bad, 8, lo, hi)
    assert nbad == 4 and sorted(bad[:nbad]) == [2, 3, 4, 5]
    assert speed == np.sqrt(2.0)


def test_simulation_allows_a_domain_size_around_the_domain():
    from hpcmpm.runner import make_domain
    from hpcmpm.scene import load_scene
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/dam_break_2d.toml")
    lo, hi = Simulation(scene, make_domain(scene)).health_bounds()
    extent = max(np.subtract(scene.domain_hi, scene.domain_lo))
    np.testing.assert_array_equal(lo, np.subtract(scene.domain_lo, extent))
    np.testing.assert_array_equal(hi, np.add(scene.domain_hi, extent))


def test_a_speed_whose_square_overflows_is_broken():
    """`scan_health`: v = (0.1, 1e299) is finite component by component, but |v|^2 is inf:
    the speed was inf, the time step 0, and the run looped at t = 0 without end (a fuzzed
    scene). The largest speed of the others is still reported."""
    from hpcmpm.kernels.particles import scan_health

    lo, hi = np.array([-1.0, -1.0]), np.array([2.0, 2.0])
    x = np.full((3, 2), 0.5)
    v = np.array([[0.1, 1e299], [3.0, 4.0], [1e154, 0.0]])  # 1e154^2 = 1e308: finite
    F = np.tile(np.eye(2), (3, 1, 1))
    bad = np.zeros(4, dtype=np.int64)
    speed, nbad = scan_health(x, v, F, bad, 4, lo, hi)
    assert nbad == 1 and bad[0] == 0
    assert speed == 1e154


def test_a_time_step_that_does_not_advance_the_run_stops_it(tmp_path, capsys):
    """A wave speed beyond the float range (E = 1e300, density = 1e-300: c = inf) gave dt =
    0 and a run that stepped forever at t = 0; now one line, exit code 3."""
    from hpcmpm import cli

    out = tmp_path / "out"
    assert cli.main(["run", "inputs/bar_2d.toml", "--out", str(out), "--quiet",
                     "--set", "materials.0.E=1e300", "--set", "materials.0.density=1e-300"]) == 3
    lines = [l for l in capsys.readouterr().err.splitlines() if l.startswith("hpcmpm:")]
    assert len(lines) == 1 and lines[0].startswith(
        "hpcmpm: error: the time step no longer advances the run at step 0, t=0: dt = 0.")


@pytest.mark.parametrize("scene, setting", [
    ("inputs/channel_hb_2d.toml", "simulation.gravity=[1e300, 0.0]"),
    ("inputs/hb_mixer_2d.toml", "colliders.2.angular_velocity=-1e308"),
])
def test_values_beyond_the_float_range_give_the_error_line_alone(scene, setting, tmp_path):
    """A gravity of 1e300 or a collider spin of 1e308 overflow |g| and the boundary speed:
    dt = 0, stopped in one line. numpy printed its RuntimeWarnings (overflow in the norms)
    before that line; the command line now sends them to the debug log
    (`cli.floating_point_errors_logged`)."""
    exe = Path(sys.executable).with_name("hpcmpm")
    proc = run_in_group([str(exe), "run", scene, "--out", str(tmp_path / "out"), "--quiet",
                         "--set", setting], timeout=120)
    assert proc.returncode == 3, proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.strip()], proc.stderr  # one line
    assert proc.stderr.startswith("hpcmpm: error: the time step no longer advances the run")
    assert "simulation.gravity" in proc.stderr


def test_a_material_update_that_divides_by_zero_stops_at_the_health_check():
    """Snow's return map divides by zero on F = diag(1e308, 1e308, 1e-308) (a fuzzed gravity
    of -1e308 got there: a ZeroDivisionError traceback, on one rank of a parallel run). That
    particle alone gets a non-finite velocity, the material a note, and the health check (on
    every rank alike) stops the run with its id."""
    import pytest

    from hpcmpm.errors import InstabilityError
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.scene import load_scene
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/snow_block_3d.toml", ["simulation.particles_per_cell=1"])
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    sim.ensure_grouped()
    p = sim.particles
    start, _ = sim.group_slices[0]
    row = start + 5
    p["F"][row] = np.diag([1e308, 1e308, 1e-308])
    sim.update_states(1e-4)
    assert np.flatnonzero(~np.isfinite(p["v"][:, 0])).tolist() == [row]
    assert sim.materials[0].failures == [
        "its state update divides by zero: a singular or non-finite deformation gradient"]
    with pytest.raises(InstabilityError) as info:
        sim.check_health()
    message = str(info.value)
    assert f"ids {int(p['id'][row])}," in message and "divides by zero" in message


def test_a_collapsing_time_step_stops_the_run_and_names_the_particle(tmp_path, capsys):
    """A Grueneisen parameter of 9.2e18 (fuzzed) keeps every value finite, but the wave speed
    runs away: taylor_cu_3d's step fell from 7.7e-8 to 1.5e-22 in 300 steps and the run then
    crawled 65 000 steps without advancing t by 1e-11. It now stops at the collapse with
    the particle of the largest wave speed, and writes no checkpoint of that state."""
    from hpcmpm import cli

    out = tmp_path / "out"
    assert cli.main(["run", "inputs/cu_shock_column_2d.toml", "--out", str(out), "--quiet",
                     "--checkpoint-every", "1",
                     "--set", "materials.0.eos.gamma0=9223372036854775808"]) == 3
    lines = [l for l in capsys.readouterr().err.splitlines() if l.startswith("hpcmpm:")]
    assert len(lines) == 1, lines
    message = lines[0]
    assert message.startswith("hpcmpm: error: the time step collapsed at step "), message
    assert re.search(r"largest wave speed is \S+ at particle id \d+ \(material 'copper'\)",
                     message), message
    assert "eos.gamma0" in message
    step = int(re.search(r"collapsed at step (\d+)", message).group(1))
    assert step < 50  # caught as it happens, not after a crawl
    steps = [int(p.stem.split("_")[1]) for p in out.glob("ckpt_*.h5")]
    assert max(steps, default=-1) < step
    for frame in out.glob("frame_*.h5"):
        with h5py.File(frame) as f:
            assert np.all(np.isfinite(f["particles/x"][...])), frame


def test_the_named_particle_is_the_one_of_the_largest_wave_speed():
    """`Simulation.fastest_signal` halves each material's slice to find its largest wave
    speed; checked against every particle's own speed, with the maximum placed at each end
    and in the middle of the slice (the halving's edge cases) and with ties."""
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.scene import load_scene
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/cu_shock_column_2d.toml")
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    p, material = sim.particles, sim.materials[0]
    sim.ensure_grouped()
    n = p.n
    rng = np.random.default_rng(7)

    def own_speed(i):
        return material.max_wave_speed({k: p[k][i:i + 1] for k in p.field_names()})

    for where in (0, n - 1, n // 2, n // 3):
        p["J"][:n] = rng.uniform(0.95, 1.0, n)
        p["J"][where] = 0.9  # compressed the most: the fastest wave
        speeds = np.array([own_speed(i) for i in range(n)])
        assert int(np.argmax(speeds)) == where
        text = sim.fastest_signal()
        expected = f"largest wave speed is {speeds[where]:.3g} at particle id {p['id'][where]}"
        assert expected in text, (text, expected)
    p["J"][:n] = 0.97  # all equal: the lowest id is named
    text = sim.fastest_signal()
    assert f"at particle id {int(np.min(p['id'][:n]))} (material 'copper')" in text.split(";")[1]


def test_a_bound_of_zero_after_positive_steps_is_a_collapse(tmp_path):
    """taylor_cu_3d with eos.gamma0 = 2e300 (crash fuzz, seed 407): after one step the wave
    speed is inf and the bound 0; the message's ratio divided by it (a ZeroDivisionError
    traceback). It is an infinite collapse."""
    from hpcmpm.errors import InstabilityError
    from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
    from hpcmpm.scene import load_scene
    from hpcmpm.simulation import Simulation

    scene = load_scene("inputs/cu_shock_column_2d.toml")
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    runner = Runner(sim, None, RunOptions(out_dir=tmp_path, end_time=1e-6, quiet=True))
    runner.check_collapse(1e-7)
    assert runner.dt_peak == 1e-7
    runner.check_collapse(2e-13)        # 5e5 times below: not yet a collapse
    with pytest.raises(InstabilityError, match=r"dt = 0, inf times below the largest step "
                                               r"of this run \(1e-07\)"):
        runner.check_collapse(0.0)

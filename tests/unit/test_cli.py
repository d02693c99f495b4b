"""Bad scenes through the console script: one line naming file and key, exit code 2, no
traceback. Each case edits a valid scene so exactly one thing is wrong."""

import sys
from pathlib import Path

import numpy as np
import pytest
from test_scene import CASES
from launch import run_in_group

GOOD = Path("inputs/disks_2d.toml").read_text()


def hpcmpm(*args, cwd=None):
    exe = Path(sys.executable).with_name("hpcmpm")
    return run_in_group([str(exe), *args], timeout=120, cwd=cwd)


# The expected lines live in test_scene.CASES; through the console script each kind of
# mistake must still be one stderr line, exit code 2, no traceback, for validate and run.
CLI_CASES = ("unknown_key", "wrong_type", "missing_end_time", "nu_half", "density", "dx",
             "body_outside", "missing_mesh", "unknown_material_type", "toml_syntax",
             "unknown_body_material", "unknown_transfer", "vector_components")


@pytest.mark.parametrize("case", CLI_CASES)
def test_bad_scene_gives_one_line_and_exit_code_2(tmp_path, case):
    text, expected = CASES[case]
    scene = tmp_path / f"{case}.toml"
    scene.write_text(text)
    for verb in ("validate", "run"):
        proc = hpcmpm(verb, str(scene), *(["--out", str(tmp_path / "out")] if verb == "run" else []))
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr + proc.stdout
        lines = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
        assert len(lines) == 1, proc.stderr
        assert f"{scene}: " in lines[0] and expected in lines[0], lines[0]


def test_every_problem_is_reported(tmp_path):
    scene = tmp_path / "many.toml"
    scene.write_text(GOOD.replace("nu = 0.3", "nu = 0.7").replace("cfl = 0.4", "cfl = -1")
                     .replace('kernel = "quadratic"', 'kernel = "quintic"'))
    proc = hpcmpm("validate", str(scene))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 3, proc.stderr
    assert any("simulation.kernel: unknown value 'quintic'" in l for l in lines)


def test_missing_file_and_valid_inputs():
    proc = hpcmpm("validate", "no/such/scene.toml")
    assert proc.returncode == 2 and "no/such/scene.toml: no such file" in proc.stderr
    # Every shipped scene in one call: a header and an "ok" line each, in the order given.
    scenes = sorted(str(p) for p in Path("inputs").glob("*.toml"))
    proc = hpcmpm("validate", *scenes)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    lines = proc.stdout.splitlines()
    assert [l[3:] for l in lines if l.startswith("== ")] == scenes
    assert [l.split(": ok (")[0] for l in lines if ": ok (" in l] == scenes


def test_several_scenes_are_each_checked_and_the_worst_exit_code_returned(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("E = 1000.0", "E = -1.0"))
    proc = hpcmpm("validate", "inputs/bar_2d.toml", str(bad), "inputs/disks_2d.toml")
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        f"hpcmpm: error: {bad}: materials[0].E: must be > 0, got -1"]
    lines = proc.stdout.splitlines()
    assert lines[0] == "== inputs/bar_2d.toml" and lines[1].startswith(
        "inputs/bar_2d.toml: ok (")
    # The bad scene's problems go to stderr; the scene after it is still checked.
    at = lines.index(f"== {bad}")
    assert lines[at + 1] == "== inputs/disks_2d.toml"
    assert lines[at + 2].startswith("inputs/disks_2d.toml: ok (")
    assert "Traceback" not in proc.stdout + proc.stderr


def test_set_overrides_and_round_trip():
    from hpcmpm.scene import load_scene, parse_scene

    scene = load_scene("inputs/disks_2d.toml", ["simulation.cfl=0.25", "materials.0.E=2000.0"])
    assert scene.cfl == 0.25 and scene.materials[0].params["E"] == 2000.0
    again = parse_scene(scene.text, path=scene.path)
    assert again == scene


def test_output_of_another_run_is_not_overwritten(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "frame_000000.h5").write_text("")
    proc = hpcmpm("run", "inputs/bar_2d.toml", "--out", str(out), "--quiet")
    assert proc.returncode == 5 and "--force" in proc.stderr



def test_force_replaces_the_other_runs_frames_and_their_pictures(tmp_path):
    """`--force` removes the other run's frames, checkpoints, XDMF and the pictures made of
    them (`hpcmpm render` / `plot` defaults); the user's own files and the job's log stay."""
    from types import SimpleNamespace

    from hpcmpm.runner import prepare_output_dir

    out = tmp_path / "out"
    (out / "render").mkdir(parents=True)
    theirs = ["frame_000033.h5", "ckpt_000000500.h5", "particles.xdmf",
              "render/render_000033.png", "render/render.mp4", "diagnostics.csv",
              "diagnostics.png"]
    kept = ["notes.txt", "slurm-42.out", "render/sketch.png"]
    for name in theirs + kept:
        (out / name).write_text("")
    comm = SimpleNamespace(rank=0, size=1, bcast=lambda obj, root=0: obj, barrier=lambda: None)
    prepare_output_dir(comm, out, force=True)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()) == \
        sorted(kept)


def test_set_on_the_command_line_and_its_problems():
    proc = hpcmpm("validate", "inputs/disks_2d.toml", "--set", "simulation.dx=0.04",
                  "--set", "bodies.0.radius=0.1")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == \
        "inputs/disks_2d.toml: ok (394 particles, 1 material, dim 2)"
    proc = hpcmpm("validate", "inputs/disks_2d.toml", "--set", "simulation.cfl=abc")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == ("hpcmpm: error: inputs/disks_2d.toml: simulation.cfl: "
                                   "must be a number, got string 'abc' "
                                   "(from --set simulation.cfl=abc)")


def test_version_usage_and_bench_pass_through():
    from hpcmpm import __version__

    proc = hpcmpm("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"hpcmpm {__version__}"
    proc = hpcmpm("validate", "inputs/bar_2d.toml", "--bogus")
    assert proc.returncode == 2 and "unrecognized arguments: --bogus" in proc.stderr
    proc = hpcmpm("bench", "--help")  # a leading option reaches the bench verb
    assert proc.returncode == 0 and "usage: hpcmpm bench" in proc.stdout


def test_main_maps_errors_and_interrupts_to_exit_codes(capsys, monkeypatch):
    from hpcmpm import cli
    from hpcmpm.errors import CheckpointError

    def fail(args):
        raise CheckpointError("ckpt.h5: checksum mismatch\nsecond line")

    def interrupt(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_info", fail)
    assert cli.main(["info", "x.h5"]) == CheckpointError.exit_code
    assert capsys.readouterr().err.splitlines() == [
        "hpcmpm: error: ckpt.h5: checksum mismatch", "hpcmpm: error: second line"]
    monkeypatch.setattr(cli, "_info", interrupt)
    assert cli.main(["info", "x.h5"]) == 130


def test_an_error_without_a_message_still_prints_a_line(capsys, monkeypatch):
    """An HpcmpmError with an empty message is told by its type: an exit code is never the
    only trace of an error."""
    from hpcmpm import cli
    from hpcmpm.errors import CheckpointError

    def fail(args):
        raise CheckpointError("")

    monkeypatch.setattr(cli, "_info", fail)
    assert cli.main(["info", "x.h5"]) == 4
    assert capsys.readouterr().err.splitlines() == ["hpcmpm: error: CheckpointError"]


def test_rank_comes_from_the_launcher_environment(monkeypatch):
    from hpcmpm import cli

    for var in ("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK", "SLURM_PROCID"):
        monkeypatch.delenv(var, raising=False)
    assert cli._rank() == 0
    monkeypatch.setenv("OMPI_COMM_WORLD_RANK", "3")
    assert cli._rank() == 3


def test_every_option_and_positional_has_help_and_the_program_says_what_it_is():
    import argparse

    from hpcmpm import cli

    parser = cli.build_parser()
    assert parser.description.startswith("hpcmpm: an MPI-distributed Material Point Method")
    assert "argument parsing" not in parser.format_help()  # the module docstring stays internal
    parsers = {"hpcmpm": parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            parsers.update({f"hpcmpm {name}": sub for name, sub in action.choices.items()})
    missing = [f"{name} {action.dest}" for name, p in parsers.items() for action in p._actions
               if not action.help and not isinstance(action, argparse._HelpAction)]
    assert missing == []
    verbs = {"run", "restart", "validate", "info", "jobscript", "bench", "render", "plot"}
    assert set(parsers) == {"hpcmpm"} | {f"hpcmpm {v}" for v in verbs}  # none escaped
    from hpcmpm.startup import counted

    assert counted(1, "material") == "1 material" and counted(2, "material") == "2 materials"


def test_a_reader_that_goes_away_ends_the_output_without_a_traceback():
    """`hpcmpm validate ... | head -1`: the pipe's reader closes before hpcmpm writes; the
    writer stops quietly with 141 (128 + SIGPIPE, what a shell reports for such a writer)."""
    import subprocess

    from launch import kill_group

    exe = Path(sys.executable).with_name("hpcmpm")
    proc = subprocess.Popen([str(exe), "validate", "inputs/bar_2d.toml", "inputs/disks_2d.toml"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        proc.stdout.close()         # before the imports are done: every write meets EPIPE
        err = proc.stderr.read()
        proc.wait(timeout=120)
    finally:
        kill_group(proc)
    assert proc.returncode == 141 and err == "", err


def test_single_process_verbs_print_once_under_a_launcher(tmp_path):
    """`mpiexec -n 2 hpcmpm validate` starts two copies of a verb that uses no MPI; rank 0
    alone prints its report (each copy printed it before), an error too, and both exit
    with the same code."""
    from launch import mpi_hpcmpm

    proc = mpi_hpcmpm(2, "validate", "inputs/bar_2d.toml")
    assert proc.stdout.count("inputs/bar_2d.toml: ok (") == 1, proc.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("E = 1000.0", "E = -1.0"))
    proc = mpi_hpcmpm(2, "validate", str(bad), check=False)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("materials[0].E: must be > 0") == 1, proc.stderr


def test_a_material_problem_found_in_the_scene_is_one_line_naming_file_and_key(tmp_path):
    """A material that can only judge itself against the whole scene (Oldroyd-B's 'fe_bdf2'
    with the semi-implicit integrator) prints `FILE: materials[i].key: ...` once; the prefix
    appeared twice ("FILE: materials[0]: FILE: materials[0].plasticity: ...")."""
    text = Path("inputs/toothpaste_3d.toml").read_text()
    assert 'type = "oldroyd_b"' in text and 'integrator = "semi_implicit"' in text
    scene = tmp_path / "paste.toml"
    scene.write_text(text.replace('type = "oldroyd_b"', 'type = "oldroyd_b"\nplasticity = '
                                  '"fe_bdf2"', 1))
    proc = hpcmpm("validate", str(scene))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines[0] == (
        f"hpcmpm: error: {scene}: materials[0].plasticity: 'fe_bdf2' runs with the explicit "
        f"integrator only (its semi-implicit force is 2/3 of the deviatoric stress); use 'fe' "
        f"or 'ob_spd'")
    assert all(line.count(str(scene)) == 1 for line in lines), lines


SNOW_SPB = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.05
end_time = 0.06
gravity = [0.0, -9.81]

[[materials]]
name = "m"
type = "snow"
density = 1000.0
E = 1e4
nu = 0.3
theta_c = 0.025
theta_s = 0.0075
xi = 10
failure = { model = "spb", grid_energy = 0.01, bond_energy = 0.5 }

[[bodies]]
material = "m"
shape = "box"
lower = [0.3, 0.2]
upper = [0.7, 0.5]
velocity = [0.0, -5.0]
"""


def test_a_blown_up_snow_spb_run_stops_as_an_instability(tmp_path):
    """Snow (xi = 10) whose particles all turn peridynamic (SPB) blows up at impact in this
    coarse scene (J_P < 0 within a few steps of landing, at cfl 0.1 too): its PD stress is at
    F^PD F_P^-1 while F_P takes the grid's compression of the PD particles, which nothing on
    the grid resists under exclusive coupling (docs/studies.md, "SPB snow blow-up"; the
    hardened wave speed in the time step only delays it). The run stops as an instability
    (exit 3, the step, time and ids on one line): it ended in a ZeroDivisionError traceback
    (F_P turned singular; `test_an_undefined_peridynamic_stress_marks_its_particles`), or in a
    MemoryError where particles flew off with finite values (the health check's bounds)."""
    scene = tmp_path / "snow_spb.toml"
    scene.write_text(SNOW_SPB)
    proc = hpcmpm("run", str(scene), "--out", str(tmp_path / "out"), "--quiet")
    assert proc.returncode == 3, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("hpcmpm: error: numerical instability at step ")


def test_an_undefined_peridynamic_stress_marks_its_particles():
    """SPB evolution, snow's PD stress F^PD F_P^-1 with one singular F_P: that particle gets
    a non-finite velocity (the health check then stops the run on every rank alike) and no
    stress, the others their stress as computed alone, and the material's failure note
    names the cause."""
    from types import SimpleNamespace

    from hpcmpm.materials import make_material
    from hpcmpm.pd.spb import SPBExtension
    from hpcmpm.scene import MaterialSpec

    snow = make_material(MaterialSpec("s", "snow", 400.0, {
        "E": 1.4e5, "nu": 0.2, "theta_c": 0.025, "theta_s": 0.0075, "xi": 10.0}), 2)
    rng = np.random.default_rng(3)
    n = 4
    Fp = np.tile(np.eye(2), (n, 1, 1)) + 0.05 * rng.standard_normal((n, 2, 2))
    Fp[2] = [[1.0, 2.0], [0.5, 1.0]]          # det 0 exactly
    fields = {"Fp": Fp, "Jp": np.linalg.det(Fp)}
    F = np.tile(np.eye(2), (n, 1, 1)) + 0.05 * rng.standard_normal((n, 2, 2))
    with pytest.raises(ZeroDivisionError):
        snow.pd_stress(fields, F, np.empty((n, 2, 2)))
    rows = np.array([5, 6, 7, 8])
    v = np.zeros((10, 2))
    tau = np.full((n, 2, 2), 7.0)
    SPBExtension._report_undefined_stress(SimpleNamespace(particles={"v": v}), snow, fields,
                                          rows, F, tau)
    assert np.isnan(v[7]).all() and np.isfinite(np.delete(v, 7, axis=0)).all()
    assert np.all(tau[2] == 0.0)
    good = [0, 1, 3]
    alone = np.empty((3, 2, 2))
    snow.pd_stress({k: a[good] for k, a in fields.items()}, F[good], alone)
    np.testing.assert_array_equal(tau[good], alone)
    assert snow.failures == ["the peridynamic stress is undefined (a singular plastic "
                             "deformation F_P, det F_P = 0)"]


def test_overlapping_bodies_are_reported_by_validate_and_run(tmp_path):
    # The upper disk moved onto the lower one: both sample the lattice points they share.
    scene = tmp_path / "overlap.toml"
    scene.write_text(GOOD.replace("center = [0.75, 0.75]", "center = [0.35, 0.25]")
                     .replace("end_time = ", "end_time = 0.001 # "))
    proc = hpcmpm("validate", str(scene))
    assert proc.returncode == 0, proc.stderr
    assert (f"{scene}: warning: bodies overlap (bodies[0] ('lower_left') and bodies[1] "
            f"('upper_right') share ") in proc.stdout
    proc = hpcmpm("run", str(scene), "--out", str(tmp_path / "out"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("warning: bodies overlap") == 1
    # The shipped scene as it is: no such line.
    assert "overlap" not in hpcmpm("validate", "inputs/disks_2d.toml").stdout

"""Rendered job scripts: valid bash, signal forwarding, and resume from the newest checkpoint
(run for real with stub scheduler commands on PATH)."""

import os
import subprocess
from pathlib import Path

import pytest

from hpcmpm.errors import EXIT_CHECKPOINTED_ON_SIGNAL
from hpcmpm.jobs import JobScriptError, render
from launch import run_in_group


@pytest.mark.parametrize("scheduler", ["slurm", "pbs"])
def test_rendered_script_is_valid_bash_with_resume_logic(tmp_path, scheduler):
    text = render(scheduler, "inputs/disks_2d.toml", 2, 8, "02:00:00", out_dir=str(tmp_path))
    script = tmp_path / "job.sh"
    script.write_text(text)
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    assert "ckpt_*.h5" in text and "hpcmpm restart" in text and "hpcmpm run" in text
    assert """trap 'signalled=1; [ -n "$pid" ] && kill -USR1 $pid""" in text
    assert str(EXIT_CHECKPOINTED_ON_SIGNAL) in text
    if scheduler == "slurm":
        assert "#SBATCH --signal=B:USR1@" in text and "scontrol requeue" in text
        assert "#SBATCH --nodes=2" in text and "#SBATCH --ntasks-per-node=8" in text
    else:
        assert "select=2:ncpus=8:mpiprocs=8" in text and "qsub" in text


def _run_with_stubs(tmp_path, scheduler, launcher, exit_code, script_name="job.sh",
                    rendered_path="", nodes=1, ranks_per_node=2, **render_args):
    """Run the rendered script with `launcher` (srun/mpiexec) replaced by a stub that records
    its arguments and exits with ``exit_code``; the requeue commands are stubs too."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    log = tmp_path / "calls.log"
    for name in (launcher, "scontrol", "qsub"):
        stub = bin_dir / name
        code = exit_code if name == launcher else 0
        stub.write_text(f'#!/usr/bin/env bash\necho "{name} $*" >> {log}\nexit {code}\n')
        stub.chmod(0o755)
    out = tmp_path / "out"
    text = render(scheduler, "scene.toml", nodes, ranks_per_node, "00:10:00", out_dir=str(out),
                  activate="true", script_path=rendered_path, **render_args)
    script = tmp_path / script_name
    script.write_text(text)
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="42")
    proc = run_in_group(["bash", str(script)], env=env, timeout=60, cwd=tmp_path)
    return proc, log.read_text().splitlines(), out


@pytest.mark.parametrize("scheduler,launcher", [("slurm", "srun"), ("pbs", "mpiexec")])
def test_script_starts_fresh_then_resumes_from_newest_checkpoint(tmp_path, scheduler, launcher):
    proc, calls, out = _run_with_stubs(tmp_path, scheduler, launcher, 0)
    assert proc.returncode == 0, proc.stderr
    assert any("hpcmpm run scene.toml" in c for c in calls), calls
    for step in (100, 200):
        (out / f"ckpt_{step:09d}.h5").write_text("")
    (tmp_path / "calls.log").unlink()
    proc, calls, _ = _run_with_stubs(tmp_path, scheduler, launcher, EXIT_CHECKPOINTED_ON_SIGNAL)
    assert proc.returncode == EXIT_CHECKPOINTED_ON_SIGNAL
    assert any(f"hpcmpm restart {out}/ckpt_000000200.h5" in c for c in calls), calls
    requeue = "scontrol requeue 42" if scheduler == "slurm" else "qsub"
    assert any(c.startswith(requeue) for c in calls), calls


def test_bad_walltime_is_a_clear_error():
    with pytest.raises(JobScriptError, match="HH:MM:SS"):
        render("slurm", "x.toml", 1, 1, "90 minutes")
    # The checkpoint signal comes at least 10 s before the end: a shorter wall time (or 0,
    # which SLURM reads as no limit) leaves it no time; 00:00:11 is the shortest.
    for walltime in ("00:00:00", "00:00:10"):
        with pytest.raises(JobScriptError, match="give more than 10 s"):
            render("slurm", "x.toml", 1, 1, walltime)
    assert "#SBATCH --signal=B:USR1@10\n" in render("slurm", "x.toml", 1, 1, "00:00:11")


@pytest.mark.parametrize("rendered", [True, False])
def test_pbs_resubmits_the_script_it_was_saved_as(tmp_path, rendered):
    # Rendered with -o: the file it was written to, even when PBS runs a copy of it (played by
    # the script run here); rendered to stdout and saved by hand: the script that runs ($0).
    # Either way not a fixed "job.sh".
    saved = tmp_path / "my_disks_run.pbs"
    proc, calls, _ = _run_with_stubs(tmp_path, "pbs", "mpiexec", EXIT_CHECKPOINTED_ON_SIGNAL,
                                     script_name="1234.server.SC",
                                     rendered_path=str(saved) if rendered else "")
    assert proc.returncode == EXIT_CHECKPOINTED_ON_SIGNAL, proc.stderr
    if rendered:
        assert f"qsub {saved}" not in calls  # the rendered file is gone: fall back to $0
        saved.write_text((tmp_path / "1234.server.SC").read_text())
        (tmp_path / "calls.log").unlink()
        proc, calls, _ = _run_with_stubs(tmp_path, "pbs", "mpiexec",
                                         EXIT_CHECKPOINTED_ON_SIGNAL,
                                         script_name="1234.server.SC", rendered_path=str(saved))
    expected = saved if rendered else tmp_path / "1234.server.SC"
    assert calls[-1] == f"qsub {expected}", calls


@pytest.mark.parametrize("mpi,expected", [("pmi2", "srun --mpi=pmi2 --kill-on-bad-exit=1"),
                                          ("pmix", "srun --mpi=pmix --kill-on-bad-exit=1"),
                                          ("default", "srun --kill-on-bad-exit=1")])
def test_srun_gets_the_mpi_plugin(tmp_path, mpi, expected):
    proc, calls, _ = _run_with_stubs(tmp_path, "slurm", "srun", 0, srun_mpi=mpi)
    assert proc.returncode == 0, proc.stderr
    assert any(c.startswith(f"{expected} hpcmpm run scene.toml") for c in calls), calls


def test_bad_mpi_plugin_is_a_clear_error():
    with pytest.raises(JobScriptError, match="--mpi: expected an srun MPI plugin"):
        render("slurm", "x.toml", 1, 1, "01:00:00", srun_mpi="pmi2; rm -rf /")


def test_jobscript_command_checks_the_run_and_creates_the_log_folder(tmp_path, monkeypatch,
                                                                        capsys):
    from hpcmpm import cli

    scene = Path("inputs/bar_2d.toml").resolve()
    monkeypatch.chdir(tmp_path)
    base = ["jobscript", "--scheduler", "slurm", "--time", "00:10:00"]
    # A scene that does not exist, or does not validate, is refused before any queue wait.
    assert cli.main([*base, "no/such/scene.toml"]) == 2
    assert "hpcmpm: error: no/such/scene.toml: no such file" in capsys.readouterr().err
    assert cli.main([*base, str(scene), "--", "--set", "simulation.cfl=-1"]) == 2
    assert "simulation.cfl: must be > 0.0, got -1" in capsys.readouterr().err
    assert cli.main([*base, str(scene), "--", "--end-time", "0"]) == 2
    assert "--end-time: must be > 0.0, got 0.0" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
    # A good one: the folder SLURM opens the log in exists before submission.
    assert cli.main([*base, str(scene), "-o", "job.sh"]) == 0
    assert (tmp_path / "runs" / "bar_2d").is_dir()
    text = (tmp_path / "job.sh").read_text()
    assert "#SBATCH --output=\"runs/bar_2d/slurm-%j.out\"" in text and "--mpi=pmi2" in text
@pytest.mark.parametrize("has_mpi,mode", [(True, "mpio"), (False, "serial")])
def test_script_writes_in_mpio_mode_when_h5py_has_mpi(tmp_path, has_mpi, mode):
    """The job runs with HPCMPM_IO_MODE=mpio exactly when the environment's h5py was built
    with MPI (a stub `python` answers the check; the stub launcher records the mode)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "calls.log"
    (bin_dir / "python").write_text(f"#!/usr/bin/env bash\nexit {0 if has_mpi else 1}\n")
    (bin_dir / "srun").write_text(
        f'#!/usr/bin/env bash\necho "mode=$HPCMPM_IO_MODE" >> {log}\nexit 0\n')
    for stub in bin_dir.iterdir():
        stub.chmod(0o755)
    script = tmp_path / "job.sh"
    script.write_text(render("slurm", "scene.toml", 1, 2, "00:10:00",
                             out_dir=str(tmp_path / "out"), activate="true"))
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="42")
    proc = subprocess.run(["bash", str(script)], env=env, capture_output=True, text=True,
                          timeout=60, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert log.read_text().split() == [f"mode={mode}"]
    assert ("serial mode" in proc.stderr) == (not has_mpi)


@pytest.mark.parametrize("nodes,ranks_per_node", [(2, 3), (1, 4), (3, 1)])
def test_pbs_starts_nodes_times_ranks_per_node_ranks(tmp_path, nodes, ranks_per_node):
    proc, calls, _ = _run_with_stubs(tmp_path, "pbs", "mpiexec", 0, nodes=nodes,
                                     ranks_per_node=ranks_per_node)
    assert proc.returncode == 0, proc.stderr
    launches = [c for c in calls if c.startswith("mpiexec ")]
    assert launches == [f"mpiexec -n {nodes * ranks_per_node} hpcmpm run scene.toml --out "
                        f"{tmp_path / 'out'} --quiet"], calls


@pytest.mark.parametrize("walltime,seconds,margin", [("02:00:00", 7200, 300),   # capped
                                                     ("00:10:00", 600, 60),     # a tenth
                                                     ("01:02:03", 3723, 300),
                                                     ("00:00:50", 50, 10)])     # at least 10 s
def test_checkpoint_signal_comes_a_tenth_of_the_wall_time_early(walltime, seconds, margin):
    """SLURM signals ``margin`` s before the end; PBS (no early warning) sleeps for the wall
    time less the margin, then signals the ranks."""
    import re

    slurm = render("slurm", "x.toml", 1, 1, walltime)
    assert f"#SBATCH --signal=B:USR1@{margin}\n" in slurm
    assert f"#SBATCH --time={walltime}\n" in slurm
    pbs = render("pbs", "x.toml", 1, 1, walltime)
    assert f"#PBS -l walltime={walltime}\n" in pbs
    sleeps = re.findall(r"sleep \$\(\((\d+) - (\d+)\)\)", pbs)
    assert sleeps == [(str(seconds), str(margin))], sleeps


def test_jobscript_defaults_and_extra_run_arguments_reach_the_script(tmp_path, monkeypatch,
                                                                     capsys):
    """Without --nodes / --ranks-per-node the job asks for 1 node with 1 rank (the documented
    defaults), and the `hpcmpm run` arguments after `--` are on the launched command line
    (`--quiet`, which the script passes anyway, once)."""
    from hpcmpm import cli

    scene = Path("inputs/bar_2d.toml").resolve()
    monkeypatch.chdir(tmp_path)
    assert cli.main(["jobscript", "--scheduler", "slurm", "--time", "00:10:00",
                     "--activate", "true", "-o", "job.sh", str(scene), "--",
                     "--end-time", "0.5", "--quiet", "--set", "simulation.cfl=0.3"]) == 0
    text = (tmp_path / "job.sh").read_text()
    assert "#SBATCH --nodes=1\n" in text and "#SBATCH --ntasks-per-node=1\n" in text
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "calls.log"
    (bin_dir / "srun").write_text(f'#!/usr/bin/env bash\necho "srun $*" >> {log}\nexit 0\n')
    (bin_dir / "srun").chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="42")
    proc = run_in_group(["bash", "job.sh"], env=env, timeout=60, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert log.read_text().splitlines() == [
        f"srun --mpi=pmi2 --kill-on-bad-exit=1 hpcmpm run {scene} --out runs/bar_2d --quiet "
        f"--end-time 0.5 --set simulation.cfl=0.3"]


@pytest.mark.parametrize("scheduler,launcher", [("slurm", "srun"), ("pbs", "mpiexec")])
def test_a_requeued_job_restarts_with_the_runs_checkpoint_options(tmp_path, scheduler, launcher):
    """The extra `hpcmpm run` arguments that a restart does not read from the checkpoint
    (--checkpoint-every, --checkpoint-wall, --debug-checks) reach the requeued job's
    `hpcmpm restart` too; those it does read (--end-time, --set: in the checkpoint) do not (a
    restart refuses --set)."""
    extra = ["--end-time", "2", "--checkpoint-every", "50", "--set", "simulation.cfl=0.3",
             "--checkpoint-wall=00:20:00", "--debug-checks"]
    proc, calls, out = _run_with_stubs(tmp_path, scheduler, launcher, 0, extra_args=extra)
    assert any(c.endswith("--quiet " + " ".join(extra)) for c in calls), calls
    (out / "ckpt_000000100.h5").write_text("")
    (tmp_path / "calls.log").unlink()
    proc, calls, _ = _run_with_stubs(tmp_path, scheduler, launcher, 0, extra_args=extra)
    assert any(c.endswith(f"hpcmpm restart {out}/ckpt_000000100.h5 --quiet --checkpoint-every "
                          f"50 --checkpoint-wall=00:20:00 --debug-checks") for c in calls), calls


def test_spaces_and_shell_characters_in_paths_reach_the_commands_whole(tmp_path):
    """A scene and an output folder named with a space, a quote and a dollar sign: the job
    name is one word the schedulers take (`job_name`), SLURM's log directive is quoted, and
    the launched command gets each path as one argument, unexpanded."""
    from hpcmpm.jobs import job_name

    out = tmp_path / "my runs" / "it's $HOME"
    proc, calls, _ = _run_with_stubs(tmp_path, "slurm", "srun", 0)
    text = render("slurm", "my scenes/disks copy (2).toml", 1, 1, "00:10:00", out_dir=str(out))
    assert "#SBATCH --job-name=disks_copy_2\n" in text
    assert f'#SBATCH --output="{out}/slurm-%j.out"\n' in text
    script = tmp_path / "spaced.sh"
    script.write_text(text.replace("\nsource ", "\n: "))   # no environment to activate
    bin_dir = tmp_path / "bin"
    (bin_dir / "srun").write_text('#!/usr/bin/env bash\nfor a in "$@"; do echo "[$a]"; done '
                                  f'>> {tmp_path}/argv.log\n')
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="42")
    assert run_in_group(["bash", str(script)], env=env, timeout=60, cwd=tmp_path).returncode == 0
    argv = (tmp_path / "argv.log").read_text().splitlines()
    assert "[my scenes/disks copy (2).toml]" in argv and f"[{out}]" in argv, argv
    assert out.is_dir()
    assert job_name("inputs/2d.toml") == "j2d" and job_name("inputs/ü.toml") == "hpcmpm"


def test_pbs_refuses_a_log_folder_it_cannot_name():
    with pytest.raises(JobScriptError, match="cannot hold a space or a quote; pass an --out"):
        render("pbs", "x.toml", 1, 1, "00:10:00", out_dir="runs/with space")
    with pytest.raises(JobScriptError, match="double quote"):
        render("slurm", "x.toml", 1, 1, "00:10:00", out_dir='runs/a"b')
    assert "#PBS -o runs/plain/pbs.out\n" in render("pbs", "x.toml", 1, 1, "00:10:00",
                                                    out_dir="runs/plain")


def test_jobscript_options_may_follow_the_scene(tmp_path, monkeypatch):
    """`hpcmpm jobscript ... SCENE -o job.sh -- --end-time 0.5`: the options after the scene
    are read and what follows `--` is the run's (argparse alone refused it)."""
    from hpcmpm import cli

    scene = Path("inputs/bar_2d.toml").resolve()
    monkeypatch.chdir(tmp_path)
    assert cli.main(["jobscript", "--scheduler", "slurm", "--time", "00:10:00", str(scene),
                     "--activate", "true", "-o", "job.sh", "--", "--end-time", "0.5"]) == 0
    assert "--quiet --end-time 0.5)" in (tmp_path / "job.sh").read_text()
    with pytest.raises(SystemExit):   # an unknown option before `--` is still refused
        cli.main(["jobscript", "--scheduler", "slurm", "--time", "00:10:00", str(scene),
                  "--bogus", "--", "--end-time", "0.5"])

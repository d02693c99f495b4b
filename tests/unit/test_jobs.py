"""Rendered job scripts: valid bash, signal forwarding, and resume from the newest checkpoint
(run for real with stub scheduler commands on PATH)."""

import os
import subprocess
from pathlib import Path

import pytest

from hpcmpm.errors import EXIT_CHECKPOINTED_ON_SIGNAL
from hpcmpm.jobs import JobScriptError, render


@pytest.mark.parametrize("scheduler", ["slurm", "pbs"])
def test_rendered_script_is_valid_bash_with_resume_logic(tmp_path, scheduler):
    text = render(scheduler, "inputs/disks_2d.toml", 2, 8, "02:00:00", out_dir=str(tmp_path))
    script = tmp_path / "job.sh"
    script.write_text(text)
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    assert "ckpt_*.h5" in text and "hpcmpm restart" in text and "hpcmpm run" in text
    assert "trap 'kill -USR1 $pid" in text
    assert str(EXIT_CHECKPOINTED_ON_SIGNAL) in text
    if scheduler == "slurm":
        assert "#SBATCH --signal=B:USR1@" in text and "scontrol requeue" in text
        assert "#SBATCH --nodes=2" in text and "#SBATCH --ntasks-per-node=8" in text
    else:
        assert "select=2:ncpus=8:mpiprocs=8" in text and "qsub" in text


def _run_with_stubs(tmp_path, scheduler, launcher, exit_code):
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
    text = render(scheduler, "scene.toml", 1, 2, "00:10:00", out_dir=str(out),
                  activate="true")
    script = tmp_path / "job.sh"
    script.write_text(text)
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_JOB_ID="42")
    proc = subprocess.run(["bash", str(script)], env=env, capture_output=True, text=True,
                          timeout=60, cwd=tmp_path)
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

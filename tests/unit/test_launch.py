"""A launch as N separate 1-rank runs (the launcher says N tasks, MPI says 1) stops at start-up
with one line naming the fix, exit code 2, nothing written. The real case (plain srun on a
cluster whose MpiDefault is none) runs in tests/mpi/test_slurm_cluster.py."""

from __future__ import annotations

import pytest

from hpcmpm import cli
from hpcmpm.errors import LaunchError
from hpcmpm.parallel import Communicator, check_launch

LAUNCH_VARIABLES = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "SLURM_STEP_NUM_TASKS")


@pytest.mark.parametrize("variable", LAUNCH_VARIABLES)
def test_n_tasks_but_one_rank_is_refused(variable):
    comm = Communicator()
    assert comm.size == 1  # this test process is a 1-rank world
    with pytest.raises(LaunchError) as info:
        check_launch(comm, {variable: "4"})
    message = str(info.value)
    assert "\n" not in message and f"{variable}=4" in message and "srun --mpi=pmi2" in message
    assert message.startswith("launched as 4 separate 1-rank runs")


@pytest.mark.parametrize("env", [{}, {"PMI_SIZE": "1"}, {"SLURM_NTASKS": "8"},
                                 {"SLURM_STEP_NUM_TASKS": "1", "PMI_SIZE": "garbage"}])
def test_a_one_task_launch_passes(env):
    # SLURM_NTASKS alone is the batch script's allocation, not a launch of this process.
    check_launch(Communicator(), env)


def test_run_stops_before_writing_anything(tmp_path, capsys, monkeypatch):
    from hpcmpm.parallel import launch

    monkeypatch.setattr(launch, "REPORT_GRACE", 0.0)  # copy 1 waits for copy 0 to report
    for variable in ("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setenv("SLURM_STEP_NUM_TASKS", "2")
    monkeypatch.setenv("SLURM_PROCID", "0")
    out = tmp_path / "out"
    assert cli.main(["run", "inputs/bar_2d.toml", "--out", str(out), "--quiet"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hpcmpm: error: launched as 2 separate")
    assert not out.exists()
    monkeypatch.setenv("SLURM_PROCID", "1")  # the other copy: same exit, no second message
    assert cli.main(["run", "inputs/bar_2d.toml", "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == ""

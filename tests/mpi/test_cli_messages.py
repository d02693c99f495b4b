"""Under ``mpiexec -n 2`` a user mistake is told once per job (rank 0), not once per rank, and
every rank exits with its code."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from launch import mpi_hpcmpm


@pytest.mark.skipif(bool(os.environ.get("PMI_SIZE") or os.environ.get("HPCMPM_MPI_CHILD")),
                    reason="launches mpiexec itself")
def test_one_message_per_job_on_two_ranks(tmp_path):
    bad_scene = tmp_path / "bad.toml"
    bad_scene.write_text(Path("inputs/bar_2d.toml").read_text().replace("cfl = 0.4", "cfl = -1"))
    cases = {
        "scene": (["run", str(bad_scene), "--out", str(tmp_path / "a")],
                  f"hpcmpm: error: {bad_scene}: simulation.cfl: must be > 0.0, got -1"),
        "option": (["run", "inputs/bar_2d.toml", "--out", str(tmp_path / "b"), "--quiet",
                    "--end-time", "-1"], "hpcmpm: error: --end-time: must be > 0.0, got -1.0"),
    }
    for case, (args, expected) in cases.items():
        proc = mpi_hpcmpm(2, *args, timeout=120, check=False)
        assert proc.returncode == 2, (case, proc.stderr)
        told = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm:")]
        assert told == [expected], (case, proc.stderr)
        assert "Traceback" not in proc.stderr

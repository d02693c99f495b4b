"""The MPI test harness (tests/conftest.py) cannot pass vacuously: a child launched for N ranks
that finds another COMM_WORLD size stops with its own exit code, and a launch ends before the
parent test's pytest-timeout, so the harness (which kills the ranks) stops it, not
pytest-timeout (which would leave them running)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

import conftest
from launch import run_in_group

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(conftest.in_mpi_child(), reason="starts a harness child itself")
def test_a_child_with_the_wrong_world_size_fails():
    # What an mpiexec of another MPI gives: N processes, each with a 1-rank COMM_WORLD. Here
    # one such process, started without mpiexec, told it is one of 2 ranks.
    env = dict(os.environ, **{conftest.CHILD_ENV: "1", conftest.RANKS_ENV: "2"})
    proc = run_in_group([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                         "tests/unit/test_shape.py"], timeout=120, cwd=ROOT, env=env)
    assert proc.returncode == conftest.WRONG_WORLD_SIZE, proc.stdout[-2000:]
    assert "launched for 2 ranks, but COMM_WORLD has 1" in proc.stdout + proc.stderr


@pytest.mark.timeout(100)
def test_the_launch_ends_before_the_tests_own_timeout(request):
    assert conftest.launch_timeout(request.node) == 100 - conftest.TIMEOUT_MARGIN


def test_without_a_marker_the_ini_timeout_bounds_the_launch(request):
    ini = float(request.config.getini("timeout") or 0)
    expected = min(conftest.MPI_TIMEOUT, ini - conftest.TIMEOUT_MARGIN) if ini else \
        conftest.MPI_TIMEOUT
    assert conftest.launch_timeout(request.node) == expected

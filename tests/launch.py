"""Subprocesses of the tests in a process group of their own, so a timeout kills the launcher
and everything it started (mpiexec's ranks, srun's tasks), not the launcher alone."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

# The virtual environment's own mpiexec (the PyPI mpich wheel's) and hpcmpm: a launcher of
# another MPI would start N separate 1-rank runs.
BIN = Path(sys.executable).parent
# One numba thread per rank: the ranks already fill the cores.
ONE_THREAD = dict(os.environ, NUMBA_NUM_THREADS="1")


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL ``proc``'s whole process group (started with ``start_new_session=True``) if any
    member is still alive; reaps ``proc``."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def run_in_group(cmd, timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """`subprocess.run(cmd, capture_output=True, text=True, timeout=...)` whose timeout kills
    the process group: raises `subprocess.TimeoutExpired` after the group is gone."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        kill_group(proc)
        proc.communicate()
        raise
    finally:
        kill_group(proc)  # nothing it started outlives it (a rank left behind by a crash)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def hpcmpm_cmd(ranks: int, *args) -> list[str]:
    """The command line `mpiexec -n ranks hpcmpm *args`."""
    return [str(BIN / "mpiexec"), "-n", str(ranks), str(BIN / "hpcmpm"), *args]


def mpi_hpcmpm(ranks: int, *args, timeout: float = 300, check: bool = True,
               env=None) -> subprocess.CompletedProcess:
    """`mpiexec -n ranks hpcmpm *args` (one numba thread per rank unless ``env``), in a process
    group killed on timeout; with ``check`` the exit code must be 0 (the assertion shows the
    end of stderr)."""
    proc = run_in_group(hpcmpm_cmd(ranks, *args), timeout=timeout,
                        env=ONE_THREAD if env is None else env)
    if check:
        assert proc.returncode == 0, proc.stderr[-3000:]
    return proc

"""Subprocesses of the tests in a process group of their own, so a timeout kills the launcher
and everything it started (mpiexec's ranks, srun's tasks), not the launcher alone."""

from __future__ import annotations

import os
import signal
import subprocess


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

"""MPI test harness (after Devito's conftest).

``@pytest.mark.parallel(ranks=[1, 2, 4])`` parametrizes a test by rank count. A 1-rank case runs
in this process. For N > 1 the parent pytest re-runs exactly that test under
``mpiexec -n N python -m mpi4py -m pytest <nodeid>`` in a subprocess with a timeout, so a
deadlock fails instead of hanging, and maps the exit code to pass/fail (the child's output is
shown on failure). Inside the child (``HPCMPM_MPI_CHILD=1``) the test body runs on every rank;
``python -m mpi4py`` turns an uncaught exception on one rank into an abort of all of them.

``shared_tmp`` is a temporary folder that all ranks of one test see (the parent makes it and
passes it down); ``tmp_path`` stays per process.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hpcmpm.numba_cache import source_fingerprint

ROOT = Path(__file__).resolve().parents[1]
# Before any test imports numba (it reads the variable once): the repository's cache for this
# state of the sources, shared with every subprocess the tests start.
os.environ.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba_cache" / source_fingerprint()))
CHILD_ENV = "HPCMPM_MPI_CHILD"
RANKS_ENV = "HPCMPM_MPI_RANKS"
SHARED_TMP_ENV = "HPCMPM_SHARED_TMP"
RANKS_ARG = "mpi_ranks"
# Wall-clock limit of one mpiexec launch; the child's own pytest-timeout fires a little
# earlier so a hang prints the stacks of the stuck rank before the launch is killed.
MPI_TIMEOUT = float(os.environ.get("HPCMPM_MPI_TIMEOUT", "240"))
# Seconds the launch must end before the parent test's own pytest-timeout, so that the harness,
# not pytest-timeout, stops it (and kills its ranks, which pytest-timeout would orphan).
TIMEOUT_MARGIN = 15
WRONG_WORLD_SIZE = 17  # exit code of a child whose COMM_WORLD is not the size it was launched for


# Set by MPICH/Hydra and Open MPI in every rank they start.
LAUNCHER_SIZE_ENVS = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE")


def launched_size() -> int | None:
    """Rank count when this process was started by mpiexec (by the harness or by hand)."""
    if os.environ.get(RANKS_ENV):
        return int(os.environ[RANKS_ENV])
    for name in LAUNCHER_SIZE_ENVS:
        if os.environ.get(name):
            return int(os.environ[name])
    return None


def in_mpi_child() -> bool:
    """True inside an mpiexec launch: the harness's own (``HPCMPM_MPI_CHILD=1``) or one started
    by hand (``mpiexec -n 4 python -m mpi4py -m pytest tests/mpi``), which then runs the cases
    for its own rank count only and never launches mpiexec again."""
    return os.environ.get(CHILD_ENV) == "1" or launched_size() is not None


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "parallel(ranks): re-run this test under mpiexec with each listed rank count")
    check_world_size()


def check_world_size() -> None:
    """In a child the harness launched for N ranks, MPI must see N ranks. An mpiexec of another
    MPI (Open MPI's on PATH, mpi4py built with MPICH) starts N separate 1-rank copies instead,
    and every halo, migration and load-balance test would pass at size 1."""
    if os.environ.get(CHILD_ENV) != "1" or not os.environ.get(RANKS_ENV):
        return
    from mpi4py import MPI

    wanted, got = int(os.environ[RANKS_ENV]), MPI.COMM_WORLD.Get_size()
    if got != wanted:
        pytest.exit(f"MPI test harness: launched for {wanted} ranks, but COMM_WORLD has {got} "
                    f"(the mpiexec does not belong to the MPI that mpi4py uses: "
                    f"{_mpiexec()})", returncode=WRONG_WORLD_SIZE)


def pytest_generate_tests(metafunc):
    marker = metafunc.definition.get_closest_marker("parallel")
    if marker is None:
        return
    ranks = list(marker.kwargs.get("ranks", marker.args[0] if marker.args else [1]))
    if in_mpi_child():
        # Same parameter id as in the parent, so the parent can name the test by its node id;
        # a test not meant for this rank count gets an empty parameter set (skipped).
        ranks = [n for n in ranks if n == launched_size()]
    if RANKS_ARG not in metafunc.fixturenames:
        metafunc.fixturenames.append(RANKS_ARG)
    metafunc.parametrize(RANKS_ARG, ranks, ids=[f"{n}rank" for n in ranks])


def _mpiexec() -> str:
    """The mpiexec of the interpreter's own environment (the PyPI mpich wheel), else PATH."""
    local = Path(sys.executable).parent / "mpiexec"
    return str(local) if local.exists() else "mpiexec"


def launch_timeout(item) -> float:
    """The mpiexec launch's limit: MPI_TIMEOUT, or less when the test's pytest-timeout (its
    marker, else the ini value) would fire first."""
    marker = item.get_closest_marker("timeout")
    limit = None
    if marker is not None and (marker.args or "timeout" in marker.kwargs):
        limit = float(marker.kwargs.get("timeout", marker.args[0] if marker.args else 0))
    elif item.config.getini("timeout"):
        limit = float(item.config.getini("timeout"))
    if not limit:
        return MPI_TIMEOUT
    return max(10.0, min(MPI_TIMEOUT, limit - TIMEOUT_MARGIN))


def _run_under_mpi(item, n_ranks: int) -> None:
    timeout = launch_timeout(item)
    env = dict(os.environ)
    env[CHILD_ENV] = "1"
    env[RANKS_ENV] = str(n_ranks)
    env.setdefault("NUMBA_NUM_THREADS", "1")
    env["NUMBA_NUM_THREADS"] = "1"
    env.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba_cache"))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    shared = item.funcargs.get("shared_tmp")
    if shared is not None:
        env[SHARED_TMP_ENV] = str(shared)
    nodeid = item.nodeid
    cmd = [_mpiexec(), "-n", str(n_ranks), sys.executable, "-m", "mpi4py", "-m", "pytest",
           nodeid, "-q", "-x", "--no-header", "-p", "no:cacheprovider",
           f"--timeout={max(5, int(timeout) - 10)}",
           # A rank stuck inside an MPI call never returns to Python, where a SIGALRM would
           # be handled: the thread method dumps the stacks and exits from a watchdog thread.
           "--timeout-method=thread", "--rootdir", str(ROOT)]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        _kill_group(proc)  # the launcher and the ranks it started
        out, _ = proc.communicate()
        timed_out = True
    finally:
        _kill_group(proc)  # also when pytest-timeout or ^C interrupts the wait
    if timed_out:
        pytest.fail(f"{nodeid} on {n_ranks} ranks did not finish in {timeout:.0f} s "
                    f"(deadlock?)\n{out[-12000:]}", pytrace=False)
    if proc.returncode == WRONG_WORLD_SIZE:
        pytest.fail(f"{nodeid}: the launch did not give {n_ranks} ranks:\n{out[-3000:]}",
                    pytrace=False)
    if proc.returncode != 0:
        pytest.fail(f"{nodeid} failed on {n_ranks} ranks (exit code {proc.returncode}):\n"
                    f"{out[-12000:]}", pytrace=False)


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem):
    if in_mpi_child() or pyfuncitem.get_closest_marker("parallel") is None:
        return None
    n_ranks = pyfuncitem.callspec.params[RANKS_ARG]
    if n_ranks == 1:
        return None  # COMM_WORLD of this very process has one rank
    _run_under_mpi(pyfuncitem, n_ranks)
    return True


@pytest.fixture
def shared_tmp(tmp_path_factory) -> Path:
    """A temporary folder shared by all ranks of an MPI test."""
    given = os.environ.get(SHARED_TMP_ENV)
    if in_mpi_child() and given:
        return Path(given)
    if in_mpi_child():  # launched by hand under mpiexec: rank 0 makes it, everybody hears
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
        path = str(tmp_path_factory.mktemp("shared")) if comm.rank == 0 else None
        return Path(comm.bcast(path))
    return tmp_path_factory.mktemp("shared")

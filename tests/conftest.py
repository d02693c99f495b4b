"""MPI test harness (after Devito's conftest).

``@pytest.mark.parallel(ranks=[1, 2, 4])`` parametrizes a test by rank count. A 1-rank case runs
in this process. For N > 1 the parent pytest re-runs exactly that test under
``mpiexec -n N python -m mpi4py -m pytest <nodeid>`` in a subprocess with a timeout, so a
deadlock fails instead of hanging. A non-zero exit fails (the child's output is shown). Each rank
of the child writes its test's outcome to a small file (hooks below, ``HPCMPM_MPI_RESULT_DIR``),
and the parent passes, skips (with the child's reason, so ``-rs`` lists it) or xfails as every
rank did; a child that exits 0 without every rank's file saying so, or whose ranks disagree,
fails, so a test skipped in the child is never reported as passed. Inside the child (``HPCMPM_MPI_CHILD=1``) the test body runs
on every rank; ``python -m mpi4py`` turns an uncaught exception on one rank into an abort of all
of them.

``shared_tmp`` is a temporary folder that all ranks of one test see (the parent makes it and
passes it down); ``tmp_path`` stays per process.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
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
# Folder where each rank of a harness child writes the outcome of its test (rank<r>.json).
RESULT_ENV = "HPCMPM_MPI_RESULT_DIR"
# Set by .ci/run: a test marked ``needs_tool`` (real ParaView, a real SLURM, the Taichi peer,
# the MPI launcher) that skips because its tool is missing fails instead, so CI cannot pass by
# skipping the real clients. Developers' machines without root keep the skips.
REQUIRE_TOOLS_ENV = "HPCMPM_REQUIRE_TOOLS"


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
    _start_recording()


# --- In a harness child: record what happened to the test, one file per rank ---------------

_record: dict = {"path": None, "reports": []}


def _start_recording() -> None:
    folder = os.environ.pop(RESULT_ENV, None)  # popped: a pytest the test starts must not write
    if not folder or os.environ.get(CHILD_ENV) != "1":
        return
    from mpi4py import MPI

    _record["path"] = Path(folder) / f"rank{MPI.COMM_WORLD.Get_rank()}.json"


def _note(report, phase: str) -> None:
    if _record["path"] is None:
        return
    outcome = report.outcome  # passed, failed, skipped
    reason = ""
    if hasattr(report, "wasxfail"):
        outcome, reason = ("xfailed", report.wasxfail) if report.skipped else (outcome, "")
    elif report.skipped:
        longrepr = report.longrepr
        reason = str(longrepr[2] if isinstance(longrepr, tuple) else longrepr)
        reason = reason.removeprefix("Skipped: ")
    _record["reports"].append({"phase": phase, "outcome": outcome, "reason": reason})


def pytest_runtest_logreport(report):
    _note(report, report.when)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    if (report.skipped and not hasattr(report, "wasxfail")
            and item.get_closest_marker("needs_tool") is not None
            and os.environ.get(REQUIRE_TOOLS_ENV) == "1"):
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
        report.outcome = "failed"
        report.longrepr = (f"{REQUIRE_TOOLS_ENV}=1 (CI), but a tool this test needs is "
                           f"missing: {reason}")


def pytest_collectreport(report):
    if not report.passed:  # a module skipped or broken at import in the child
        _note(report, "collect")


def pytest_sessionfinish(session, exitstatus):
    path = _record["path"]
    if path is None:
        return
    data = {"exitstatus": int(exitstatus), "reports": _record["reports"]}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data))
    os.replace(tmp, path)  # the parent never reads half a file


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
    results = Path(tempfile.mkdtemp(prefix="hpcmpm-mpi-result-"))
    env[RESULT_ENV] = str(results)
    try:
        out = _launch(item, n_ranks, timeout, env)
        _report_child_outcome(item.nodeid, n_ranks, results, out)
    finally:
        shutil.rmtree(results, ignore_errors=True)


def _launch(item, n_ranks: int, timeout: float, env: dict) -> str:
    """Run the test under mpiexec; fail on a timeout or a non-zero exit, else return the
    child's output."""
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
    return out


def _rank_outcome(reports: list[dict]) -> tuple[str, str]:
    """(outcome, reason) of one rank's test from its setup/call/teardown reports."""
    for r in reports:
        if r["outcome"] == "failed":
            return "failed", f"{r['phase']} failed"
    for r in reports:
        if r["outcome"] in ("skipped", "xfailed"):
            return r["outcome"], r["reason"]
    if any(r["phase"] == "call" and r["outcome"] == "passed" for r in reports):
        return "passed", ""
    return "unknown", "no report of the test itself"


def _report_child_outcome(nodeid: str, n_ranks: int, results: Path, out: str) -> None:
    """Pass, skip (with the child's reason) or xfail as the child's test did on every rank; a
    child that exited 0 without every rank's result saying passed, skipped or xfailed, or
    whose ranks disagree, fails."""
    where = f"{nodeid} on {n_ranks} ranks"
    outcomes = {}
    for rank in range(n_ranks):
        try:
            data = json.loads((results / f"rank{rank}.json").read_text())
            outcomes[rank] = _rank_outcome(data["reports"])
        except (OSError, ValueError, KeyError, TypeError) as err:
            outcomes[rank] = ("unknown", f"no readable result ({type(err).__name__}: {err})")
    bad = {r: o for r, o in outcomes.items() if o[0] in ("failed", "unknown")}
    if bad:
        pytest.fail(f"{where}: the child exited 0, but its outcome is not a pass or skip on "
                    f"every rank: {bad}\n{out[-12000:]}", pytrace=False)
    if len({o[0] for o in outcomes.values()}) > 1:
        # Ranks that disagree (one skips, another passes) ran different tests: a rank-count
        # dependence, not a result.
        pytest.fail(f"{where}: the ranks' outcomes differ: {outcomes}\n{out[-12000:]}",
                    pytrace=False)
    outcome, reason = outcomes[0]
    if outcome == "skipped":
        # Listed by ``-rs`` at the test's own file and line, as a skip in this process is.
        raise pytest.skip.Exception(reason or f"skipped on {n_ranks} ranks",
                                    _use_item_location=True)
    if outcome == "xfailed":
        pytest.xfail(reason)


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

"""Decide together, fail together: an uncaught exception on one rank aborts all of them
(`Domain.install_abort_hook`), instead of leaving the others in a collective forever."""

import os
import sys
import textwrap
from pathlib import Path

import pytest
from launch import run_in_group

SCRIPT = textwrap.dedent("""
    import numpy as np
    from hpcmpm.parallel import Domain

    domain = Domain(2, 0.1, np.zeros(2), np.ones(2))
    domain.install_abort_hook()
    if domain.rank == 1:
        raise RuntimeError("rank 1 gives up")
    domain.barrier()  # rank 0 would wait here forever without the hook
""")


@pytest.mark.skipif(bool(os.environ.get("PMI_SIZE") or os.environ.get("HPCMPM_MPI_CHILD")),
                    reason="launches mpiexec itself")
def test_exception_on_one_rank_aborts_all():
    mpiexec = Path(sys.executable).parent / "mpiexec"
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root), NUMBA_NUM_THREADS="1")
    proc = run_in_group([str(mpiexec if mpiexec.exists() else "mpiexec"), "-n", "2",
                         sys.executable, "-c", SCRIPT], cwd=root, env=env, timeout=60)
    assert proc.returncode != 0
    assert "rank 1 gives up" in proc.stderr

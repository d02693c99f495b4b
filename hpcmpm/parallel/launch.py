"""Start-up check of how the ranks were launched.

A launcher that does not speak the MPI library's process-management interface starts N
unconnected copies, each with a 1-rank ``COMM_WORLD`` (SLURM's ``srun`` without ``--mpi=pmi2``
on a cluster whose MpiDefault is none; another MPI's ``mpiexec``). They would all write the same
output folder at once. The launcher still tells each copy how many tasks it started; when that
says N > 1 and MPI says 1, the run stops before writing anything.
"""

from __future__ import annotations

import os
import time
from typing import Mapping

from ..errors import LaunchError
from ..launcher import launched_tasks, launcher_rank
from .comm import Communicator

# Seconds the copies other than the launcher's rank 0 wait before they exit: copy 0 reports
# and exits first, and `srun --kill-on-bad-exit` may stop the others, never copy 0 unheard.
REPORT_GRACE = 2.0


def check_launch(comm: Communicator | None = None,
                 env: Mapping[str, str] | None = None) -> None:
    """Raise `LaunchError` (exit 2) when the launcher started N > 1 tasks but this process's
    ``COMM_WORLD`` has one rank: one line naming the fix."""
    comm = comm or Communicator()
    env = os.environ if env is None else env
    found = launched_tasks(env)
    if found is None or comm.size != 1:
        return
    count, name, launcher = found
    if launcher_rank(env) != 0:
        time.sleep(REPORT_GRACE)
    from mpi4py import MPI

    library = " ".join(MPI.Get_library_version().strip().splitlines()[0].split())
    raise LaunchError(
        f"launched as {count} separate 1-rank runs: {launcher} started {count} tasks "
        f"({name}={count}) but MPI ({library}) sees one rank in each; under SLURM use "
        f"`srun --mpi=pmi2` (or the plugin your MPI needs: `hpcmpm jobscript --mpi`), "
        f"otherwise the mpiexec of the MPI that mpi4py uses")

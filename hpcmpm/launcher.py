"""What the launcher (mpiexec, srun) tells each process it starts through the environment: its
rank and the number of tasks. Read without importing MPI, so the CLI can use it for messages;
`hpcmpm.parallel.launch` compares it with what MPI says."""

from __future__ import annotations

import os
from typing import Mapping

# Set by MPICH/Hydra and PMI-2 (PMI_*), Open MPI, PMIx and srun, in that order of preference.
RANK_VARIABLES = ("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK", "SLURM_PROCID")

# (variable, who sets it): the task count each launcher gives the processes it starts.
TASK_COUNT_VARIABLES = (
    ("PMI_SIZE", "the PMI launcher (mpiexec of MPICH, srun --mpi=pmi2)"),
    ("OMPI_COMM_WORLD_SIZE", "Open MPI's mpiexec"),
    ("SLURM_STEP_NUM_TASKS", "srun"),  # set for job steps only, not in the batch script
)


def launcher_rank(env: Mapping[str, str] | None = None) -> int:
    """This process's rank as its launcher numbered it (0 when not launched by one)."""
    env = os.environ if env is None else env
    for name in RANK_VARIABLES:
        try:
            return int(env[name])
        except (KeyError, ValueError):
            continue
    return 0


def launched_tasks(env: Mapping[str, str] | None = None) -> tuple[int, str, str] | None:
    """(task count, variable, launcher) of the first launcher variable that says > 1 task."""
    env = os.environ if env is None else env
    for name, launcher in TASK_COUNT_VARIABLES:
        try:
            count = int(env.get(name, ""))
        except ValueError:
            continue
        if count > 1:
            return count, name, launcher
    return None

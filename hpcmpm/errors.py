"""One exception family; the CLI turns each into one line and an exit code."""


class HpcmpmError(Exception):
    """Base of every error hpcmpm reports to a user.

    Contract: under MPI an HpcmpmError is raised on every rank alike (decided together: a
    broadcast, a reduction, or a check every rank makes on the same data), so the CLI prints it
    on rank 0 only and every rank exits with ``exit_code``. A failure that only one rank sees
    is not an HpcmpmError: it goes to the abort hook (`Domain.install_abort_hook`)."""

    exit_code = 1
    label = "error"  # the CLI prints "hpcmpm: {label}: {message}"


class SceneError(HpcmpmError):
    """A scene file is invalid; ``problems`` holds one line per problem."""

    exit_code = 2

    def __init__(self, problems: list[str] | str):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class InstabilityError(HpcmpmError):
    """The simulation blew up (non-finite value, det F <= 0, a particle far outside)."""

    exit_code = 3


class CheckpointError(HpcmpmError):
    """A checkpoint cannot be written or read back."""

    exit_code = 4


class FrameError(HpcmpmError):
    """A frame cannot be written (raised on every rank: no rank is left in a collective)."""

    exit_code = 4


class OutputExistsError(HpcmpmError):
    """An output folder already holds another run's output."""

    exit_code = 5


# Exit code for a run that stopped on SIGTERM/SIGUSR1 after writing a checkpoint.
# Job scripts requeue on this code (jobs/*.sh.in).
EXIT_CHECKPOINTED_ON_SIGNAL = 75


class LaunchError(HpcmpmError):
    """The ranks were started wrongly (e.g. N separate 1-rank runs instead of one N-rank run);
    raised before anything is written."""

    exit_code = 2

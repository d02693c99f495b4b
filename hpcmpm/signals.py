"""The scheduler's early-warning signals (SIGTERM, SIGUSR1), caught and kept for the run loop."""

from __future__ import annotations

import signal


class SignalFlag:
    """Set by SIGTERM/SIGUSR1 (what SLURM sends ahead of the wall time); read at step
    boundaries only, so a checkpoint is never written from inside a step."""

    SIGNALS = (signal.SIGTERM, signal.SIGUSR1)

    def __init__(self) -> None:
        self.raised: int | None = None
        self._previous = {}

    def __enter__(self):
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        self.raised = signum

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False

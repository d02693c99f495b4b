"""The scheduler's warning signals are kept for the run loop, and only while it runs."""

from __future__ import annotations

import os
import signal

import pytest

from hpcmpm.signals import SignalFlag


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGUSR1])
def test_warning_signal_is_kept_and_the_previous_handler_restored(sig):
    seen = []
    previous = signal.signal(sig, lambda signum, frame: seen.append(signum))
    try:
        with SignalFlag() as flag:
            assert flag.raised is None
            os.kill(os.getpid(), sig)  # delivered to the main thread before kill returns
            assert flag.raised == sig  # the run loop checkpoints on this
        assert seen == []  # caught by the flag, not by the handler it replaced
        os.kill(os.getpid(), sig)
        assert seen == [sig]  # after the run, the process's own handler is back
    finally:
        signal.signal(sig, previous)

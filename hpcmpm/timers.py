"""Per-phase wall-time counters: `with timers("p2g"): ...` accumulates seconds per phase."""

from __future__ import annotations

import time
from contextlib import contextmanager


class PhaseTimers:
    """Accumulated wall time and call count per named phase."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def __call__(self, phase: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - start
            self.calls[phase] = self.calls.get(phase, 0) + 1

    def reset(self) -> None:
        self.seconds.clear()
        self.calls.clear()

    def total(self) -> float:
        return sum(self.seconds.values())

    def report(self) -> str:
        total = self.total() or 1.0
        rows = sorted(self.seconds.items(), key=lambda kv: -kv[1])
        return ", ".join(f"{k} {v:.3f}s ({100 * v / total:.0f}%)" for k, v in rows)

"""Progress bar of a run (rank 0 only): simulated time, step, dt, particle-steps/s, ETA."""

from __future__ import annotations

import math
import sys
import time

from tqdm import tqdm


BAR_FORMAT = "{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]"
COMPILING_FORMAT = "{l_bar}{bar}| t={n:.4g}/{total:.4g} [compiling, first step]"
# A run without an end (`--end-time inf`, stopped by a signal): no bar, no ETA.
OPEN_FORMAT = "t={n:.4g} [{elapsed}{postfix}]"
OPEN_COMPILING_FORMAT = "t={n:.4g} [compiling, first step]"


class Progress:
    """A tqdm bar over simulated time; ``disabled`` for --quiet and ranks other than 0."""

    def __init__(self, end_time: float, n_particles: int, disabled: bool = False):
        self.end_time = end_time
        self.n_particles = n_particles
        self.disabled = bool(disabled)
        self.bar = None
        self._t0 = 0.0
        self._step0 = 0
        self._last_refresh = 0.0
        self._timed = False

    def start(self, sim_time: float, step: int) -> None:
        self._t0 = time.perf_counter()
        self._step0 = step
        self._timed = False
        if self.disabled:
            return
        # Until the first step is done its time is mostly compilation: no ETA from it.
        ends = math.isfinite(self.end_time)
        self.bar = tqdm(total=self.end_time if ends else None, initial=sim_time, unit="t",
                        file=sys.stderr, dynamic_ncols=True, leave=True,
                        bar_format=COMPILING_FORMAT if ends else OPEN_COMPILING_FORMAT)
        self.bar.refresh()

    def update(self, sim_time: float, step: int, dt: float) -> None:
        if self.bar is None:
            return
        now = time.perf_counter()
        if not self._timed:
            # The first step is done: rate and ETA count from here (tqdm's from its start_t
            # and initial), so the kernels' compilation does not inflate the ETA.
            self._timed = True
            self._t0, self._step0 = now, step
            self.bar.start_t = self.bar._time()
            self.bar.initial = self.bar.n = min(sim_time, self.end_time)
            self.bar.bar_format = BAR_FORMAT if math.isfinite(self.end_time) else OPEN_FORMAT
            self.bar.set_postfix_str(f"step {step}, dt {dt:.3g}", refresh=False)
            self.bar.refresh()
            self._last_refresh = now
            return
        if now - self._last_refresh < 0.5 and sim_time < self.end_time:
            return  # redrawing every step would cost more than small steps take
        self._last_refresh = now
        rate = self.n_particles * (step - self._step0) / max(now - self._t0, 1e-9)
        self.bar.n = min(sim_time, self.end_time)
        self.bar.set_postfix_str(f"step {step}, dt {dt:.3g}, {rate:.3g} particle-steps/s",
                                 refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.n = min(self.bar.n, self.end_time)
            self.bar.close()
            self.bar = None

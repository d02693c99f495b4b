"""The progress bar says "compiling" until the first step is done, then times the run from
there: the kernels' compilation (seconds to a minute) must not turn into an ETA of hours."""

from __future__ import annotations

import time

from hpcmpm.progress import Progress


def test_no_eta_while_compiling_then_eta_from_the_first_timed_step(capsys):
    progress = Progress(end_time=1.0, n_particles=100)
    progress.start(0.0, 0)
    assert "compiling, first step" in str(progress.bar)
    compile_time = 0.3
    time.sleep(compile_time)  # the first step: mostly compilation
    progress.update(0.1, 1, 0.1)
    text = str(progress.bar)
    assert "compiling" not in text and "step 1" in text
    time.sleep(0.02)
    progress.update(1.0, 10, 0.1)  # the last step: drawn whatever the redraw interval
    meter = progress.bar.format_dict
    # tqdm's rate is (n - initial) / elapsed: both count from the end of the first step.
    assert meter["initial"] == 0.1 and meter["n"] == 1.0
    assert meter["elapsed"] < compile_time, meter["elapsed"]
    progress.close()
    assert "compiling" in capsys.readouterr().err  # it was shown to the user


def test_rate_counts_the_timed_steps_over_the_timed_wall_time(monkeypatch):
    """particle-steps/s = particles x steps since the first step / wall time since it, on a
    clock set by hand: 100 particles, steps 1 -> 11 in 2 s after 30 s of compilation is
    500, not 100 x 11 / 2 nor 100 x 10 / 32."""
    from hpcmpm import progress as module

    now = [0.0]
    monkeypatch.setattr(module.time, "perf_counter", lambda: now[0])
    bar = Progress(end_time=1.0, n_particles=100)
    bar.start(0.0, 0)
    now[0] = 30.0
    bar.update(0.1, 1, 0.1)  # the first step: compiled, timing starts here
    now[0] = 32.0
    bar.update(0.5, 11, 0.04)
    assert "step 11, dt 0.04, 500 particle-steps/s" in str(bar.bar)
    bar.close()


def test_a_run_without_an_end_shows_time_and_rate_without_a_bar(capsys):
    """`hpcmpm run --end-time inf` (a run stopped by the scheduler's signal): tqdm cannot
    draw a bar to infinity (it raised a TypeError in the first redraw); the line shows the
    simulated time, the step and the rate, no total and no ETA."""
    progress = Progress(end_time=float("inf"), n_particles=100)
    progress.start(0.0, 0)
    assert "compiling, first step" in str(progress.bar)
    progress.update(0.1, 1, 0.1)
    time.sleep(0.6)                      # past the redraw interval
    progress.update(0.35, 5, 0.1)
    text = str(progress.bar)
    assert text.startswith("t=0.35 [") and "step 5" in text and "particle-steps/s" in text
    assert "inf" not in text and "<" not in text
    progress.close()
    assert "t=0.35" in capsys.readouterr().err

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

"""Integral-based MPM (003 ch. 5) on the round-1 bar: the correspondence bond force through
the grid gives the first-mode period T = 4L/c = 10 (inputs/ibmpm_bar_2d.toml) within 2 %,
the error falling with dx at a fixed horizon in spacings. With the PD clamp at the sticky
fixed end (the default, hpcmpm/pd/clamp.py) it falls at second order; without it, at first."""

import pytest
from test_bar_vibration import L, PERIOD, period_and_amplitude

from hpcmpm.scene import load_scene


def period_error(cells: int, clamp: str) -> float:
    scene = load_scene("inputs/ibmpm_bar_2d.toml",
                       [f"simulation.dx={L / cells}", "simulation.end_time=8.0",
                        f'materials.1.clamp="{clamp}"'])
    return abs(period_and_amplitude(scene, axis=0)[0] - PERIOD) / PERIOD


@pytest.mark.parametrize("clamp", ["auto", "none"])
def test_ibmpm_bar_period(clamp):
    errors = [period_error(c, clamp) for c in (25, 50)]
    print(f"integral-based MPM bar, clamp {clamp}: period errors at 25, 50 cells: {errors}")
    # The 2 % at both resolutions.
    assert errors[0] < 2e-2 and errors[1] < 2e-2
    if clamp == "auto":
        # Measured 0.106 % and 0.022 % (0.0051 % at 100 cells, left out for time): order
        # 2.25 then 2.13. Halving dx must cut the error by more than 2^1.5: the clamp makes
        # the fixed end exact for the affine fields near it, and what is left is second order.
        assert errors[0] < 2e-3
        assert errors[1] < errors[0] / 2 ** 1.5
    else:
        # Without the clamp the wall cuts the families of the fixed end, a compliant layer
        # of width ~delta: measured 1.15 % and 0.60 % (0.27 % at 100 cells), first order.
        # The bound separates it from the clamped case (an order of magnitude smaller).
        assert errors[0] > 5e-3
        assert errors[1] < 0.7 * errors[0]

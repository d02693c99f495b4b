"""Integral-based MPM (003 ch. 5) on the round-1 bar: the correspondence bond force through
the grid gives the first-mode period T = 4L/c = 10 (inputs/ibmpm_bar_2d.toml) within 2 %,
the error falling with dx at a fixed horizon in spacings."""

from test_bar_vibration import PERIOD, run_bar


def test_ibmpm_bar_period():
    errors = [abs(run_bar(c, path="inputs/ibmpm_bar_2d.toml")[0] - PERIOD) / PERIOD
              for c in (25, 50)]
    print(f"integral-based MPM bar period errors at 25, 50 cells: {errors}")
    # The 2 %; measured 1.15 % and 0.60 % (and 0.27 % at 100 cells, left out for
    # time). The error comes from the PD layer of width ~delta at the free end: first order.
    assert errors[0] < 2e-2 and errors[1] < 2e-2
    assert errors[1] < 0.7 * errors[0]

"""Axial vibration of an elastic bar: the first mode's period and centre-of-mass velocity.

Reference (e.g. Bardenhagen 2004; the standard MPM bar test): a bar of length L fixed at x = 0,
free at x = L, with v(x, 0) = v0 sin(pi x / 2L). With E = 100, rho = 1, nu = 0, L = 25, the wave
speed is c = 10, the period T = 4L / c = 10 and the centre-of-mass velocity is
v_cm(t) = (2 v0 / pi) cos(2 pi t / T).
"""

import os
from pathlib import Path

import numpy as np
import pytest

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene
from hpcmpm.viz.plots import curve_against_reference

L, V0, PERIOD = 25.0, 0.1, 10.0
VCM_AMPLITUDE = 2 * V0 / np.pi


def run_bar(cells: int, transfer: str = "mls", history_out: list | None = None,
            path: str = "inputs/bar_2d.toml"):
    """Period and |v_cm| at half a period, measured from the v_cm(t) history (appended to
    ``history_out`` as (t, v_cm) arrays when given) of the bar scene at ``path``."""
    scene = load_scene(path,
                       [f"simulation.dx={L / cells}", "simulation.end_time=8.0",
                        f'simulation.transfer="{transfer}"'])
    return period_and_amplitude(scene, axis=0, history_out=history_out)


def period_and_amplitude(scene, axis: int, history_out: list | None = None):
    """Period and |v_cm| at half a period of the axial mode along ``axis`` (the (t, v_cm)
    history appended to ``history_out`` when given)."""
    history = []

    def observe(sim):
        p = sim.particles
        history.append((sim.time, (p["mass"] * p["v"][:, axis]).sum() / p["mass"].sum()))

    simulate(scene, observer=observe)
    t, v = np.array(history).T
    if history_out is not None:
        history_out.append((t, v))
    # Zero crossings of v_cm (linear interpolation) at T/4 and 3T/4.
    i = np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))[:2]
    zeros = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    period = 2 * (zeros[1] - zeros[0])
    return period, np.abs(v.min())


def test_bar_period_and_velocity_at_50_cells(tmp_path):
    history = []
    period, vmin = run_bar(50, history_out=history)
    # Issue requirement: period within 0.5 % and v_cm amplitude within 2 % at 50 cells.
    assert abs(period - PERIOD) / PERIOD < 5e-3
    assert abs(vmin - VCM_AMPLITUDE) / VCM_AMPLITUDE < 2e-2
    # The whole curve against the analytic one, plotted (HPCMPM_PLOT_DIR=docs/img writes the
    # figure of docs/studies.md). Those two requirements bound the deviation up to t = 8: a
    # 0.5 % period error shifts the phase by at most 2 pi (8 / T) 5e-3 = 0.025 rad (2.5 % of
    # the amplitude), plus the 2 % amplitude error (measured: 2.3 %).
    t, v = history[0]
    out = Path(os.environ.get("HPCMPM_PLOT_DIR", tmp_path)) / "verification_bar_vcm.png"
    deviation = curve_against_reference(
        out, t, v, lambda s: VCM_AMPLITUDE * np.cos(2 * np.pi * s / PERIOD),
        label="hpcmpm, 50 cells (MLS)", reference_label="(2 v0 / pi) cos(2 pi t / T)",
        xlabel="t", ylabel="centre-of-mass velocity", relative_to=VCM_AMPLITUDE,
        title="axial bar: v_cm against the analytic first mode")
    assert np.abs(deviation).max() < 2 * np.pi * t.max() / PERIOD * 5e-3 + 2e-2
    assert out.stat().st_size > 5000


def test_bar_period_converges():
    errors = [abs(run_bar(c)[0] - PERIOD) / PERIOD for c in (25, 50, 100)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(f"bar period errors {errors}, observed orders {orders}")
    # The error falls at every refinement. The observed order is about 1: the free end of a
    # particle body sits within O(dx) of its true position (the MPM free-surface error), which
    # dominates the O(dx^2) interior error of B-spline MPM; 0.8 leaves room for noise.
    assert errors[0] > errors[1] > errors[2]
    assert np.all(orders > 0.8)


@pytest.mark.parametrize("transfer", ["pic", "flip", "apic"])
def test_bar_period_with_the_other_transfers(transfer):
    (p25, v25), (p50, v50) = run_bar(25, transfer), run_bar(50, transfer)
    e25, e50 = abs(p25 - PERIOD) / PERIOD, abs(p50 - PERIOD) / PERIOD
    print(f"{transfer}: period errors {e25:.2e} (25 cells), {e50:.2e} (50 cells); v_cm "
          f"amplitude errors {(v25 - VCM_AMPLITUDE) / VCM_AMPLITUDE:.2e}, "
          f"{(v50 - VCM_AMPLITUDE) / VCM_AMPLITUDE:.2e}")
    # Measured 0.63 % (PIC 0.62 %, FLIP 0.64 %, APIC 0.63 %) at 50 cells: first order like MLS
    # (the free end's O(dx) position error), with a larger constant since their gradient is
    # not MLS's. 1 % is the bound; the error must halve from 25 to 50 cells (order > 0.8,
    # as for MLS).
    assert e50 < 1e-2
    assert np.log2(e25 / e50) > 0.8
    if transfer == "pic":
        # PIC dissipates: the amplitude falls short, by an error of first order in dx
        # (measured -5.9 % and -3.0 %), so it must shrink with refinement, not only stay small.
        assert v50 < VCM_AMPLITUDE and v25 < v50
        assert (VCM_AMPLITUDE - v50) / VCM_AMPLITUDE < 0.05
        assert np.log2((VCM_AMPLITUDE - v25) / (VCM_AMPLITUDE - v50)) > 0.8   # 0.97 measured
    else:
        # FLIP and APIC keep the amplitude (measured -0.15 % and -0.005 %), like MLS.
        assert abs(v50 - VCM_AMPLITUDE) / VCM_AMPLITUDE < 2e-2


BAR_3D = """
[simulation]
dim = 3
domain = { lower = [0.0, 0.0, 0.0], upper = [2.0, 2.0, 30.0] }
dx = 0.5
particles_per_cell = 2
transfer = "mls"
end_time = 8.0

[[materials]]
name = "bar"
type = "linear_elastic"
density = 1.0
E = 100.0
nu = 0.0

[[bodies]]
name = "bar"
material = "bar"
shape = "box"
lower = [0.5, 0.5, 0.0]
upper = [1.5, 1.5, 25.0]
velocity_field = { type = "axial_mode", amplitude = 0.1, length = 25.0, axis = 2 }

[walls]
default = "slip"
z_lower = { condition = "sticky" }
"""


def test_bar_in_3d_along_z():
    """The same bar as a 3D body along z (the axis 2D never exercises): with nu = 0 the axial
    mode is the 1D one, so the analytic period T = 4L/c = 10 and v_cm amplitude 2 v0 / pi
    hold in 3D too."""
    from hpcmpm.scene import parse_scene

    period, vmin = period_and_amplitude(parse_scene(BAR_3D, "bar_3d"), axis=2)
    print(f"3D bar: period error {(period - PERIOD) / PERIOD:.2e}, amplitude error "
          f"{(vmin - VCM_AMPLITUDE) / VCM_AMPLITUDE:.2e}")
    # The 2D bar's bounds at 50 cells (measured in 3D: 0.36 % and 0.01 %).
    assert abs(period - PERIOD) / PERIOD < 5e-3
    assert abs(vmin - VCM_AMPLITUDE) / VCM_AMPLITUDE < 2e-2

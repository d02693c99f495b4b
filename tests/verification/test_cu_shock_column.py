"""The Hugoniot test in MPM: a copper column hits a rigid wall at 500 m/s (inputs/
cu_shock_column_2d.toml). Behind the shock the copper must sit at the jump-condition state of
the linear U_s-u_p fit the Mie-Grüneisen EOS is built on (Marsh 1980 copper): front speed
relative to the material U_s - u_p = 4185 m/s, p = rho0 U_s u_p = 20.92 GPa,
rho/rho0 = U_s/(U_s - u_p) = 1.1195. Tolerances are the issue's: 2 %, 3 %, 1 %."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene
from hpcmpm.viz.plots import curve_against_reference

RHO0, C0, S, U_P = 8930.0, 3940.0, 1.49, 500.0
U_S = C0 + S * U_P
J_H = (U_S - U_P) / U_S
P_H = RHO0 * U_S * U_P


@pytest.fixture(scope="module")
def frames():
    """(t, x, J, pressure) at the scene's frame times (output.every)."""
    scene = load_scene("inputs/cu_shock_column_2d.toml")
    every = scene.output.every
    loaded = []

    def observe(sim):
        if sim.time >= len(loaded) * every:
            p = sim.particles
            loaded.append((sim.time, p["x"][:, 0].copy(), p["J"].copy(),
                           p["pressure"].copy()))

    simulate(scene, observer=observe)
    return loaded


def front(x: np.ndarray, J: np.ndarray) -> float:
    """The front: the farthest particle from the wall already halfway to J_H."""
    return float(x[J < 0.5 * (1 + J_H)].max())


def test_frames_cover_the_crossing(frames):
    assert len(frames) >= 10  # at least 10 frames with the shock in the column
    assert front(*frames[-1][1:3]) > 0.7 * 0.1


def test_shock_speed_pressure_and_density(frames):
    times = np.array([t for t, *_ in frames[1:]])
    fronts = np.array([front(x, J) for _, x, J, _ in frames[1:]])
    # Lab-frame front speed (the shocked copper is at rest): U_s - u_p. A least-squares line
    # through the later frames, past the start-up at the wall.
    speed = np.polyfit(times[3:], fronts[3:], 1)[0]
    print(f"front speed {speed:.1f} m/s, U_s - u_p = {U_S - U_P:.0f} m/s "
          f"({speed / (U_S - U_P) - 1:+.2e})")
    assert abs(speed / (U_S - U_P) - 1) <= 0.02
    for t, x, J, p in frames[4:]:
        # The plateau: away from the wall (wall heating) and from the front (its width).
        xf = front(x, J)
        plateau = (x > 0.15 * xf) & (x < 0.75 * xf)
        # Cross-section means: across the column the particles next to the slip walls are
        # denser than the middle ones by ~1.5 % (an MPM wall effect a fluid has no shear
        # to even out); the mean is the 1D state.
        p_mean, rho_mean = p[plateau].mean(), (1 / J[plateau]).mean()
        print(f"t = {t:.2e}: p/p_H - 1 = {p_mean / P_H - 1:+.2e}, "
              f"rho/rho_H - 1 = {rho_mean * J_H - 1:+.2e}")
        assert abs(p_mean / P_H - 1) <= 0.03
        assert abs(rho_mean * J_H - 1) <= 0.01


def test_pressure_profile_plotted(frames, tmp_path):
    """The last frame's pressure along the column, averaged over each cell-wide slice, over the
    jump-condition step (p_H behind the front at (U_s - u_p) t, 0 ahead), with the difference
    underneath (HPCMPM_PLOT_DIR=docs/img writes the figure of docs/studies.md). The plateau
    slices obey the 3 % of the test above; what is plotted is what is asserted."""
    t, x, J, p = frames[-1]
    dx = load_scene("inputs/cu_shock_column_2d.toml").dx
    slot = np.floor(x / dx).astype(np.int64)
    counts = np.bincount(slot)
    keep = counts > 0
    centres = ((np.arange(len(counts)) + 0.5) * dx)[keep]
    mean_p = np.bincount(slot, weights=p)[keep] / counts[keep]
    xs = (U_S - U_P) * t

    def jump(s):
        return np.where(np.asarray(s) < xs, P_H, 0.0)

    out = Path(os.environ.get("HPCMPM_PLOT_DIR", tmp_path)) / "verification_shock_column.png"
    difference = curve_against_reference(
        out, centres * 1e3, mean_p / 1e9, lambda s: jump(s * 1e-3) / 1e9,
        label="hpcmpm, slice means", reference_label="jump conditions (U_s - u_p) t, p_H",
        xlabel="x (mm)", ylabel="pressure (GPa)", relative_to=P_H / 1e9,
        title=f"Cu column at 500 m/s, t = {t * 1e6:.1f} us: pressure against the Hugoniot")
    xf = front(x, J)
    plateau = (centres > 0.15 * xf) & (centres < 0.75 * xf)
    assert plateau.sum() >= 10
    assert np.abs(difference[plateau]).max() <= 0.03
    assert out.stat().st_size > 5000

"""Results do not depend on a uniform velocity added to everything in a periodic box: a scene
made periodic along every axis and boosted by u = k dx / dt (whole cells each step) gives the
unboosted run translated by u t, with velocities raised by u, to round-off.

Whole cells, because MPM is Galilean invariant only on the grid's lattice: the partition of
unity adds u to every node's velocity and leaves grad v alone, and a particle moved by whole
cells keeps its weights, so every step of the boosted run is the still run's step shifted.
Every axis periodic, since a wall or a box at rest is not boosted with the rest.

What it checks is the periodic bookkeeping under steady wrapping: the boosted bodies cross the
faces every few steps (PD families and bonds, their reference positions and pre-cracks, SPB
conversions, prescribed sets turning about a centre that wraps, the semi-implicit solve). A
quantity that keeps an unwrapped position, or a wrap that forgets a field, shows here.
What is left is round-off from positions rounded at another magnitude (x + k dx), amplified
over the steps (measured below, per case).
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hpcmpm.scene import apply_overrides
from scene_helpers import run_scene, write_scene

ROOT = Path(__file__).resolve().parents[2]
AXES = "xyz"

CASES = [
    # (scene, end time, fixed dt, boost in cells per step, extra settings, what it covers)
    # 800 steps at one cell a step along the diagonal: the halves wrap 16 times each way
    # and tear at the pre-crack (measured |dv| 5e-11 of the largest velocity).
    ("pd_plate_tear_2d", 1e-3, 1.25e-6, [1, 1], [],
     "PD off the grid, a pre-crack, tearing"),
    # The coarse, fast-pulled bar of test_orientation_symmetry: 20 cells across the period,
    # crossed 5 times (measured 3e-13).
    ("spb_stretched_bar_2d", 4e-3, 4e-5, [1, 0],
     ["simulation.dx=0.014", "materials.0.failure.grid_energy=3376.8",
      "materials.0.failure.bond_energy=0.5", "prescribed.0.velocity=[0.0, -3.0]",
      "prescribed.1.velocity=[0.0, 3.0]"],
     "SPB-MPM: prescribed regions, conversions, broken bonds"),
    # The channel, now periodic across too, solved tight: CG stops relative to |M v*|,
    # which the boost changes (measured 3e-14).
    ("channel_bingham_2d", 0.1, 0.01, [1, 1],
     ["solver.tolerance=1e-12", "solver.newton_tolerance=1e-11"],
     "semi-implicit Newton, Bingham"),
    # 9 cells a step along y and z: the bar crosses both faces in 5 steps while its twisted
    # end turns about its wrapping centre (measured 4e-11).
    ("sponge_twist_ob_3d", 0.01, 2e-3, [0, 9, 9], ["solver.tolerance=1e-12"],
     "3D semi-implicit, a prescribed set turning about a centre that wraps"),
    # 4 cells a step along x and z: 40 cells in 10 steps, the periods are 30 and 25.
    ("pd_jelly_stretch_3d", 0.01, 1e-3, [4, 0, 4], [], "3D PD with grid coupling"),
]


def boosted_pair(raw: dict, dt: float, cells: list[int], tmp: Path, scene: str):
    """The scene ``raw`` made periodic along every axis without walls, written still and
    boosted; returns the two paths and u."""
    dim = raw["simulation"]["dim"]
    raw["simulation"]["periodic"] = list(AXES[:dim])
    raw.pop("walls", None)
    u = np.array(cells, float) * raw["simulation"]["dx"] / dt
    paths = []
    for name, boost in (("still", np.zeros(dim)), ("boosted", u)):
        scene_raw = copy.deepcopy(raw)
        for table in ("bodies", "prescribed"):
            for entry in scene_raw.get(table, []):
                entry["velocity"] = [float(a + b) for a, b in
                                     zip(entry.get("velocity", [0.0] * dim), boost)]
        paths.append(write_scene(tmp / name, scene, scene_raw))
    return paths, u


@pytest.mark.parametrize("scene, end_time, dt, cells, extra, covers", CASES,
                         ids=[c[0] for c in CASES])
def test_a_boosted_periodic_scene_gives_the_translated_result(tmp_path, scene, end_time, dt,
                                                              cells, extra, covers):
    raw = tomllib.loads((ROOT / "inputs" / f"{scene}.toml").read_text())
    sets = [f"simulation.end_time={end_time}", f"output.every={end_time}",
            f"simulation.dt={dt}", *extra]
    assert not apply_overrides(raw, sets, scene)
    (still, boosted), u = boosted_pair(raw, dt, cells, tmp_path, scene)
    _, a = run_scene(still, fields=None)
    _, b = run_scene(boosted, fields=None)
    steps = a["steps"]
    assert steps == b["steps"] > 0
    # Whole steps only: a shortened last step would move by a fraction of a cell.
    assert a["time"] == b["time"] == pytest.approx(steps * dt, rel=1e-12)
    assert np.array_equal(a["id"], b["id"])     # the same lattice, the same ids
    domain = raw["simulation"]["domain"]
    period = np.array(domain["upper"]) - np.array(domain["lower"])
    # The boost must carry every particle across a face, or little periodic is tested.
    assert np.any(np.abs(u) * steps * dt >= period)

    def periods_apart(d):
        return d - period * np.round(d / period)

    # 1e-9 of the scale, as in test_orientation_symmetry: round-off amplified over the steps
    # (measured at most 9e-13 of the period in x).
    shift = periods_apart(b["x"] - (a["x"] + steps * dt * u))
    assert np.abs(shift).max() <= 1e-9 * period.max(), f"{covers}: x"
    # Velocities relative to the boosted run's: v + u is rounded relative to |u|, and the
    # implicit solves stop relative to |M v*|, which carries u too (measured at most 1.3e-12).
    assert np.abs(a["v"]).max() > 0.0
    assert np.abs(b["v"] - u - a["v"]).max() <= 1e-9 * np.abs(b["v"]).max(), f"{covers}: v"
    # Every other particle field is the same, reference positions up to whole periods (a
    # PD particle's x0 wraps with it). Velocity gradients (L, APIC's C) sum u grad w_ip, zero
    # up to round-off of |u| / dx; the rest to 1e-9 of their largest value (measured at most
    # 4.5e-11, the sponge's b: its CG stops relative to |M v*|); integers exactly.
    checked = set()
    for name in a.keys() - {"id", "x", "v", "steps", "time"}:
        want, got = a[name], b[name]
        if name == "x0":
            assert np.abs(periods_apart(got - want)).max() <= 1e-9 * period.max()
        elif want.dtype.kind in "iub":
            assert np.array_equal(got, want), f"{covers}: {name}"
        else:
            scale = np.abs(want).max()
            if name in ("L", "C"):
                scale = max(scale, np.abs(u).max() / raw["simulation"]["dx"])
            assert np.abs(got - want).max() <= 1e-9 * scale, f"{covers}: {name}"
        checked.add(name)
    assert checked >= {"mass", "C"}
    if scene == "pd_plate_tear_2d":
        assert (a["damage"] > 0).sum() > 100
    if scene == "spb_stretched_bar_2d":
        assert (a["model"] == 1).sum() > 100 and a["damage"].max() > 0.1

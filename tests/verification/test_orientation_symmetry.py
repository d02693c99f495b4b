"""Results do not depend on how a scene is oriented in the grid: a 2D scene mirrored across
the diagonal (x <-> y) and a 3D scene with its axes turned cyclically (x -> y -> z -> x) give
the mirrored / turned particles, velocities and deformation gradients, to round-off.

The whole scene turns with the axes: the domain, bodies, velocities, gravity, colliders,
prescribed regions, walls (``x_lower`` becomes ``y_lower``), periodic axes, pre-cracks and an
axial velocity field's axis. The isotropic materials and the grid's per-axis kernels must then
reproduce the turned run, so a kernel that mixes up two axes (a stride, a wall's face, an
offset applied to the wrong component) fails here. The particles of both runs are paired by
their initial positions (the same lattice, turned). What is left is the summation order: a
node's neighbours and a particle's bonds are visited in another order, so the runs differ by
round-off, amplified over the steps (measured: at most 6.2e-12 of the largest velocity, the
mixer; 0 to 9.3e-14 of the largest coordinate). The implicit solves are tightened to 1e-10,
since CG stops at a residual whose iterates depend on the order: at the scenes' own 1e-6 the
mirrored mixer differs by 4e-8 of its largest velocity after 14 steps (measured), at 1e-8 by
9e-10, at 1e-10 by 2e-11.
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
VECTOR_KEYS = {"lower", "upper", "velocity", "gravity", "center", "half_extents", "point",
               "normal", "axis", "translate"}
AXIS_NAMES = "xyz"


def turned(raw: dict, perm: list[int]) -> dict:
    """The scene ``raw`` (parsed TOML) with its axes permuted: new axis i is old axis
    perm[i]. A key that carries an orientation this does not know (a box rotation) stops the
    test rather than leave it unturned."""
    dim = len(perm)
    where = {old: new for new, old in enumerate(perm)}
    proper = np.linalg.det(np.eye(dim)[perm]) > 0

    def axis_name(name: str) -> str:
        return AXIS_NAMES[where[AXIS_NAMES.index(name)]]

    def walk(obj, key=None):
        if isinstance(obj, dict):
            out = {}
            for k, v in obj.items():
                if key == "walls" and k[:1] in AXIS_NAMES and k[1:] in ("_lower", "_upper"):
                    k = axis_name(k[0]) + k[1:]
                out[k] = walk(v, k)
            return out
        if key in ("rotation", "rotations"):
            raise NotImplementedError(f"turning a scene with '{key}'")
        if key in VECTOR_KEYS and isinstance(obj, list) and len(obj) == dim:
            return [obj[a] for a in perm]
        if key == "axis" and isinstance(obj, int):
            return where[obj]
        if key == "periodic":
            return [axis_name(a) for a in obj]
        if key == "precracks":
            return [[[point[a] for a in perm] for point in segment] for segment in obj]
        if key == "angular_velocity":
            if dim == 3:
                return [obj[a] for a in perm]
            return obj if proper else -obj      # 2D: the in-plane spin, mirrored
        if isinstance(obj, list):
            return [walk(v, key) for v in obj]
        return obj

    return walk(copy.deepcopy(raw))


def pair(start_a: dict, start_b: dict, perm: list[int]) -> np.ndarray:
    """For each id of run a (ascending), the id of the particle of run b that started at its
    turned position."""
    ids_a = np.array(sorted(start_a))
    ids_b = np.array(sorted(start_b))
    xa = np.array([start_a[i] for i in ids_a])[:, perm]
    xb = np.array([start_b[i] for i in ids_b])
    oa = np.lexsort(np.round(xa, 12).T[::-1])
    ob = np.lexsort(np.round(xb, 12).T[::-1])
    # The lattice points are computed per axis by the same formula: bitwise the same.
    assert np.array_equal(xa[oa], xb[ob])
    out = np.empty(len(ids_a), np.int64)
    out[oa] = ids_b[ob]
    return out


CASES = [
    # (scene, end time, extra settings, what it covers)
    ("pd_plate_tear_2d", 2e-3, [], "PD off the grid, a pre-crack, tearing (1226 steps)"),
    # The coarse, fast-pulled bar of tests/mpi/test_spb_ranks.py: 200 steps convert 816 of
    # 1120 particles and break bonds.
    ("spb_stretched_bar_2d", 8e-3, ["simulation.dx=0.014", "simulation.dt=4e-5",
                                    "materials.0.failure.grid_energy=3376.8",
                                    "materials.0.failure.bond_energy=0.5",
                                    "prescribed.0.velocity=[0.0, -3.0]",
                                    "prescribed.1.velocity=[0.0, 3.0]"],
     "SPB-MPM: prescribed regions, conversions, broken bonds"),
    ("cu_shock_column_2d", 2e-6, [], "a sticky x_lower wall, Mie-Grueneisen"),
    ("bar_2d", 0.3, [], "an axial velocity field along x, a sticky x_lower wall"),
    ("ibmpm_wall_fracture_2d", 0.01, [], "integral-based MPM with the PD clamp"),
    ("channel_bingham_2d", 0.2, ["solver.tolerance=1e-10", "solver.newton_tolerance=1e-10"],
     "periodic along x, semi-implicit Newton, Bingham"),
    ("hb_mixer_2d", 0.03, ["solver.tolerance=1e-10"],
     "turning colliders, semi-implicit, volume averaging"),
    ("pd_jelly_stretch_3d", 0.03, [], "3D PD with grid coupling"),
    ("sponge_twist_ob_3d", 0.01, ["solver.tolerance=1e-10"],
     "3D semi-implicit, a prescribed set turning about x"),
]


@pytest.mark.parametrize("scene, end_time, extra, covers", CASES, ids=[c[0] for c in CASES])
def test_a_turned_scene_gives_the_turned_result(tmp_path, scene, end_time, extra, covers):
    raw = tomllib.loads((ROOT / "inputs" / f"{scene}.toml").read_text())
    # Settings go in before the turn: a velocity set here turns with the scene.
    sets = [f"simulation.end_time={end_time}", f"output.every={end_time}", *extra]
    assert not apply_overrides(raw, sets, scene)
    dim = raw["simulation"]["dim"]
    perm = [1, 0] if dim == 2 else [2, 0, 1]
    paths = [write_scene(tmp_path / name, scene, scene_raw)
             for name, scene_raw in (("as_given", raw), ("turned", turned(raw, perm)))]
    start_a, a = run_scene(paths[0])
    start_b, b = run_scene(paths[1])
    assert a["steps"] == b["steps"] > 0
    partner = pair(start_a, start_b, perm)
    rows_b = np.searchsorted(b["id"], partner)
    assert np.array_equal(b["id"][rows_b], partner)
    # 1e-9 of the largest value: round-off from the visiting order, amplified over the steps
    # (measured at most 6.2e-12; a wall left on the wrong face moves particles by 1e-3 of the
    # domain and velocities by 90 %).
    for name in ("x", "v"):
        got = b[name][rows_b]
        want = a[name][:, perm]
        scale = np.abs(want).max()
        assert np.abs(got - want).max() <= 1e-9 * scale, f"{covers}: {name}"
    if "F" in a:
        F = a["F"].reshape(-1, dim, dim)[:, perm][:, :, perm]
        got = b["F"][rows_b].reshape(-1, dim, dim)
        assert np.abs(got - F).max() <= 1e-9 * np.abs(F).max(), f"{covers}: F"
    # The same particles convert (SPB) and the same bonds break (round-off could only flip
    # a bond sitting on its critical stretch). Damage sums a family's intact share in
    # partner-id order, which the turn changes: equal to round-off, where one more or one
    # fewer broken bond would move it by 1/36 or more.
    if "model" in a:
        assert np.array_equal(b["model"][rows_b], a["model"]), f"{covers}: model"
    if "damage" in a:
        assert np.abs(b["damage"][rows_b] - a["damage"]).max() < 1e-12, f"{covers}: damage"
    if scene == "spb_stretched_bar_2d":
        assert (a["model"] == 1).sum() > 100 and a["damage"].max() > 0.1
    if scene == "pd_plate_tear_2d":
        assert (a["damage"] > 0).sum() > 100

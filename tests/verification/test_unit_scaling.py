"""A scene restated in other units gives the same run in those units, bitwise.

Lengths are multiplied by S = 2^20, densities by R = 2^-30 and times by T = 2^10, and every
scene key by the powers of S, R and T that its dimension carries (`KEYS`): a velocity by
S / T, a modulus (R S^2 / T^2) and a fracture energy (R S^3 / T^2) by theirs. Multiplying by a
power of two is exact in binary floating point and commutes with rounding, so a code that only
ever combines quantities in dimensionally consistent formulas computes every number of the
scaled run as exactly that power of two times the original: positions x S, velocities x S / T,
F and b alike, masses x R S^d, stresses x R S^2 / T^2 (`field_exponents`). An absolute
constant hidden in a formula (a distance tolerance of 1e-12, a "mass > 1e-10" node test, a
time-step floor) breaks that, and a user working in millimetres, grams or microseconds gets
another result: this test finds it. Measured over every scene in inputs/ (a tenth of each
run): all bitwise in lengths and densities, and in time where the Herschel-Bulkley flow index
is 1; psi_p of the bond-plasticity model scales as R^2 S^-4 T^-4 in 3D, R^2 S^-2 T^-4 in 2D
(below). A flow index h != 1 puts time into pow(rate, h), which is not exact under scaling
(channel_hb_2d, h = 0.5: 2e-8 in L), so such scenes keep T = 1.
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
R = 2.0 ** -30    # densities
S = 2.0 ** 20     # lengths
T = 2.0 ** 10     # times

# Scene keys by their (density, length, time) exponents. Keys in no table are dimensionless
# (Poisson's ratio, stretches, strains, spacings, temperatures, friction, counts); a numeric
# key this test does not know stops it.
LENGTH = {"dx", "lower", "upper", "center", "radius", "length", "half_extents", "point",
          "half_length", "translate", "scale", "horizon_length", "precracks"}
TIME = {"end_time", "dt", "max_dt", "every", "start", "end", "relaxation_time"}
STRESS = {"E", "mu", "lambda", "A", "B"}
KEYS = {**{k: (0, 1, 0) for k in LENGTH},
        **{k: (0, 0, 1) for k in TIME},
        **{k: (1, 2, -2) for k in STRESS},
        "velocity": (0, 1, -1), "amplitude": (0, 1, -1), "c0": (0, 1, -1),
        "gravity": (0, 1, -2), "angular_velocity": (0, 0, -1), "eps_dot0": (0, 0, -1),
        "density": (1, 0, 0),
        "viscosity": (1, 2, -1),                                    # stress x time
        "fracture_energy": (1, 3, -2), "bond_energy": (1, 3, -2),   # stress x length
        "specific_heat": (0, 2, -2)}                                # velocity^2 per kelvin
DIMENSIONLESS = {"nu", "critical_stretch", "crack_threshold", "gamma0", "s", "flow_index",
                 "C", "T_melt", "T_room", "m", "n", "horizon", "theta_c", "theta_s", "xi",
                 "yield_strain", "stabilization", "max_bond_stretch", "skin", "q1", "q2",
                 "max_exponent", "normal", "axis", "friction", "jitter", "seed", "rotation",
                 "cfl", "dim", "particles_per_cell", "tolerance", "newton_tolerance",
                 "max_iterations", "plastic_yield_stretch"}


def special(key: str, table: dict, dim: int) -> tuple[float, float, float] | None:
    """Exponents of the keys whose dimension depends on the model or another key."""
    if key == "plastic_yield":
        # psi_p is compared with E_dev^2 / 2, E_dev = w beta (2 mu + lambda) e / |X| and
        # beta = d^2 K / ((2 mu + lambda) sum_q w V_q) (pd/bond_energy.py): a stress over a
        # volume and a length, squared.
        return (2, 2 - 2 * dim, -4)
    if key == "grid_energy":
        # G = l0 sum_p w_ip m_p EE_p / m_i (003 eq. 6.10): a length times EE, which is
        # sigma+ : sigma+ or, for "tensile_energy", an energy per volume.
        return (1, 3, -2) if table.get("energy") == "tensile_energy" else (2, 5, -4)
    if key == "flow_consistency":
        return (0, 0, table.get("flow_index", 1.0))                  # time^h
    return None


def rescaled(raw: dict, r: float, s: float, t: float) -> dict:
    dim = raw["simulation"]["dim"]

    def factor(key, table):
        exps = special(key, table, dim) or KEYS.get(key)
        if exps is None:
            if key in DIMENSIONLESS:
                return 1.0
            raise NotImplementedError(f"the dimension of scene key {key!r}")
        f = r ** exps[0] * s ** exps[1] * t ** exps[2]
        assert f == 2.0 ** round(np.log2(f)), f"{key}: {f} is no power of two"
        return f

    def walk(obj, key=None, table=None):
        if isinstance(obj, dict):
            return {k: walk(v, k, obj) for k, v in obj.items()}
        if isinstance(obj, list):
            return [walk(v, key, table) for v in obj]
        if isinstance(obj, bool) or not isinstance(obj, (int, float)):
            return obj
        f = factor(key, table)
        return obj if f == 1.0 else obj * f     # integers (dim, seeds) stay integers

    out = walk(copy.deepcopy(raw))
    for body, scaled in zip(raw.get("bodies", []), out.get("bodies", [])):
        if body.get("shape") == "mesh" and "scale" not in body:
            scaled["scale"] = s       # the file's coordinates are lengths too
    return out


def field_exponents(dim: int, energy: str) -> dict[str, tuple[int, int, int]]:
    """How each particle field scales; a field not named here must not change."""
    stress = (1, 2, -2)
    return {"x": (0, 1, 0), "x0": (0, 1, 0), "v": (0, 1, -1), "C": (0, 0, -1),
            "L": (0, 0, -1), "mass": (1, dim, 0), "vol0": (0, dim, 0),
            "pd_wvol0": (0, dim, 0), "pd_m": (0, dim + 2, 0), "E": stress,
            "pressure": stress, "s": stress,
            "EE": stress if energy == "tensile_energy" else (2, 4, -4)}


CASES = [
    # (scene, end time as a fraction of the scene's, extra settings, what it covers); times
    # scale by T unless the scene has a flow index other than 1 (module docstring)
    ("kalthoff_winkler_2d", 0.3, [], "PD off the grid, pre-cracks, fracture energy"),
    ("spb_stretched_bar_2d", 1.0, ["simulation.dx=0.014", "simulation.dt=4e-5",
                                   "simulation.end_time=8e-3",
                                   "materials.0.failure.grid_energy=3376.8",
                                   "materials.0.failure.bond_energy=0.5",
                                   "prescribed.0.velocity=[0.0, -3.0]",
                                   "prescribed.1.velocity=[0.0, 3.0]"],
     "SPB-MPM: grid energy, conversions, bond energy failure"),
    ("ibmpm_ball_board_3d", 0.1, [], "integral-based MPM, 3D bond plasticity, contact"),
    # 410 steps: the wall has yielded and 182 particles have broken bonds (psi_p's 2D
    # exponent: with 3D's the positions differ, tried).
    ("ibmpm_wall_fracture_2d", 0.2, [], "2D bond plasticity, fracture, the PD clamp"),
    ("taylor_cu_3d", 0.1, [], "a mesh body, J2 with Johnson-Cook, Mie-Grueneisen"),
    ("hb_mixer_2d", 0.1, [], "semi-implicit Herschel-Bulkley, turning colliders"),
    ("watermelon_3d", 0.1, [], "SPB impact, stretch failure, mesh bodies"),
]


@pytest.mark.parametrize("scene, fraction, extra, covers", CASES, ids=[c[0] for c in CASES])
def test_a_scene_in_other_units_gives_the_same_run_bitwise(tmp_path, scene, fraction, extra,
                                                           covers):
    raw = tomllib.loads((ROOT / "inputs" / f"{scene}.toml").read_text())
    assert not apply_overrides(raw, extra, scene)
    end = raw["simulation"]["end_time"] * fraction
    assert not apply_overrides(raw, [f"simulation.end_time={end}", f"output.every={end}"],
                               scene)
    flow_indices = {m.get("flow_index", 1.0) for m in raw["materials"]}
    t = T if flow_indices <= {1.0} else 1.0
    paths = [write_scene(tmp_path / name, scene, scene_raw)
             for name, scene_raw in (("si", raw), ("scaled", rescaled(raw, R, S, t)))]
    _, a = run_scene(paths[0], fields=None)
    _, b = run_scene(paths[1], fields=None)
    assert a["steps"] == b["steps"] > 0
    assert b["time"] == a["time"] * t
    dim = raw["simulation"]["dim"]
    energies = [m["failure"].get("energy", "stress_squared")
                for m in raw["materials"] if "failure" in m]
    exponents = field_exponents(dim, energies[0] if energies else "stress_squared")
    assert a.keys() == b.keys()
    for name in a.keys() - {"steps", "time"}:
        i, j, k = exponents.get(name, (0, 0, 0))
        want = a[name] * (R ** i * S ** j * t ** k) if a[name].dtype.kind == "f" else a[name]
        assert np.array_equal(b[name], want, equal_nan=True), f"{covers}: {name}"
    assert np.abs(a["v"]).max() > 0.0
    if scene == "spb_stretched_bar_2d":
        assert (a["model"] == 1).sum() > 100 and a["damage"].max() > 0.1
    if scene in ("kalthoff_winkler_2d", "ibmpm_wall_fracture_2d"):
        assert (a["damage"] > 0).sum() > 0

"""Smoke runs of scripts/study_pd_models.py and scripts/study_kalthoff_winkler.py (tiny
sizes): they exit 0 and write finite numbers for every measurement; the measured values
(nu_eff, energy drift, memory = "none" viscosity, crack angles) are in their full runs,
reported in docs/studies.md."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def numbers(obj):
    if isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from numbers(v)


def test_study_pd_models_smoke(tmp_path):
    out = tmp_path / "study.json"
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "study_pd_models.py"),
                           "--smoke", "--out", str(out)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    data = json.loads(out.read_text())
    assert all(math.isfinite(v) for v in numbers(data))
    assert {e["model"] for e in data["energy"]} == {"bond_energy", "lps"}
    assert data["elastic_constants"][0]["dim"] == 2
    assert data["viscoelastic"]["maxwell"] and data["viscoelastic"]["none"]


def test_study_kalthoff_winkler_smoke(tmp_path):
    out = tmp_path / "kw.json"
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "study_kalthoff_winkler.py"),
                           "--smoke", "--out", str(out)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (row,) = json.loads(out.read_text())
    assert row["steps"] > 0 and row["particles"] == 800
    assert all(math.isfinite(row[k]) for k in ("s0", "dt", "wall_s"))


def test_kalthoff_winkler_angle_extrapolation():
    """The dx -> 0 limit the study prints: exact for angles on a line, NaN without two."""
    sys.path.insert(0, str(REPO / "scripts"))
    from study_kalthoff_winkler import extrapolated_angle

    assert math.isclose(extrapolated_angle([1e-3, 0.5e-3], [60.0, 65.0]), 70.0, rel_tol=1e-12)
    assert math.isnan(extrapolated_angle([1e-3, 0.5e-3], [60.0, math.nan]))



def test_kalthoff_winkler_notch_gap():
    """--notch-width cuts each notch as a gap: at 1 mm spacing a 2 mm gap leaves out the two
    rows beside each notch line (y = +-24.5 and +-25.5 mm) for its 50 columns, and nothing
    beyond the notch tip (x > 50 mm) or beside the gap."""
    sys.path.insert(0, str(REPO / "scripts"))
    from study_kalthoff_winkler import plate

    full, _ = plate(1e-3)
    cut, ids = plate(1e-3, notch_width=2e-3)
    assert len(full) - len(cut) == 2 * 2 * 50
    assert np.array_equal(ids, np.arange(len(cut)))
    def tenths_of_mm(points):
        return {tuple(p) for p in np.rint(points * 1e4).astype(int)}

    gone = np.array(sorted(tenths_of_mm(full) - tenths_of_mm(cut)))
    assert set(np.abs(gone[:, 1])) == {245, 255}
    assert gone[:, 0].max() < 500

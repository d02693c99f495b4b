"""Smoke runs of the accuracy and stability studies (tiny sizes): each script exits 0 and
writes its outputs with finite numbers. No timing is asserted; the measured numbers are in
docs/studies.md."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / "scripts"


def run_script(name: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    env.setdefault("NUMBA_CACHE_DIR", str(REPO / ".numba_cache"))
    result = subprocess.run([sys.executable, str(SCRIPTS / name), *args], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, \
        f"{name} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def numbers(obj):
    if isinstance(obj, bool) or obj is None:
        return
    if isinstance(obj, (int, float)):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from numbers(v)


def test_study_error_smoke(tmp_path):
    png = tmp_path / "study_error.png"
    run_script("study_error.py", "--smoke", "--out-dir", str(tmp_path), "--png", str(png))
    rows = list(csv.DictReader(open(tmp_path / "study_error.csv")))
    assert {r["problem"] for r in rows} == {"bar", "mms"}
    assert {r["transfer"] for r in rows} == {"pic", "flip", "apic", "mls"}
    assert {r["kernel"] for r in rows} == {"quadratic", "cubic"}
    for r in rows:
        for key in ("dx", "error", "wall_s", "order"):
            assert math.isfinite(float(r[key])), (key, r)
        assert float(r["error"]) >= 0.0
    assert png.stat().st_size > 1000


def test_study_stability_smoke(tmp_path):
    run_script("study_stability.py", "--smoke", "--out-dir", str(tmp_path))
    result = json.loads((tmp_path / "study_stability.json").read_text())
    assert set(result) >= {"cfl", "extreme", "energy_drift"}
    for scene in ("bar", "disks"):
        for tr in ("pic", "flip", "apic", "mls"):
            assert tr in result["cfl"][scene]
    jelly = result["extreme"]["jelly_dt_5x_cfl"]
    assert jelly["cli"]["all_frames_finite"]
    if jelly["outcome"] == "InstabilityError":
        assert jelly["cli"]["exit_code"] == 3
        assert jelly["message_names_step_time_ids"]
    for r in result["extreme"].values():
        assert r["acceptable"]
    for key in ("cfl", "energy_drift"):
        values = list(numbers(result[key]))
        assert values and all(math.isfinite(v) for v in values)
    assert (tmp_path / "study_stability.md").read_text().startswith("| scheme")

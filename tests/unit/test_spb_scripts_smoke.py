"""Smoke runs of the SPB-MPM study and benchmark scripts (tiny sizes): each exits 0 and prints
finite numbers. No timing is asserted; the measured numbers are in the scripts' docstrings
and the report."""

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def run_script(*args: str) -> str:
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    result = subprocess.run([sys.executable, *args], cwd=REPO, env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, f"{args} failed:\n{result.stderr[-3000:]}"
    return result.stdout


def test_study_spb_bar_smoke():
    out = run_script("scripts/study_spb_bar.py", "--smoke")
    assert "dx = 0.028" in out and "first conversion at t =" in out
    assert "nan" not in out.lower()


def test_bench_spb_overhead_smoke():
    out = run_script("scripts/bench_spb_overhead.py", "inputs/spb_stretched_bar_2d.toml",
                     "--steps", "3", "--warm", "2")
    rows = [line for line in out.splitlines() if "ms/step" in line]
    assert [r.split()[0] for r in rows] == ["mpm", "unreached", "as_written"]
    assert all(re.search(r"\d+\.\d+ ms/step", r) for r in rows)

"""Smoke run of scripts/fuzz_equivalence.py (one trial: the PD bar with APIC on 1 and 2
ranks, restarted on 2 and on 1): the script runs, and its trial passes its own rank and
restart comparisons. No timing is asserted."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from launch import run_in_group

REPO = Path(__file__).resolve().parents[2]


def test_fuzz_equivalence_smoke():
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    proc = run_in_group([sys.executable, str(REPO / "scripts" / "fuzz_equivalence.py"),
                         "--count", "1", "--scenes", "ibmpm_bar_2d", "--changes",
                         'simulation.transfer="apic"'], cwd=REPO, env=env, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert lines[0] == '1: ibmpm_bar_2d simulation.transfer="apic": ok', lines
    assert lines[-1].startswith("1 trials in") and "{'ok': 1}" in lines[-1], lines

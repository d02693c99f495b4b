"""Smoke run of scripts/bench_pd.py on a tiny lattice: it runs and reports finite, positive
rates. No timing is asserted (the measured numbers are in the lead's BENCHMARKS.md)."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_bench_pd_smoke(tmp_path):
    out = tmp_path / "pd.json"
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    result = subprocess.run([sys.executable, str(REPO / "scripts" / "bench_pd.py"), "--n", "10",
                             "--repeat", "1", "--json", str(out)], cwd=REPO, env=env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    data = json.loads(out.read_text())
    for family in ("truncated", "partial_volumes"):
        rates = data[family]
        assert rates["bytes_per_half_bond"] == 22
        for key in ("pmb_ceiling", "pmb", "lps_ceiling", "lps"):
            assert math.isfinite(rates[key]) and rates[key] > 0

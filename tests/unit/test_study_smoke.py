"""Smoke runs of the accuracy and stability studies (tiny sizes): each script exits 0 and
writes its outputs with finite numbers; the error study's Taichi peer matches hpcmpm on the bar
(or is skipped with a reason when Taichi is absent). No timing is asserted; the measured numbers
are in docs/studies.md."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from launch import run_in_group

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / "scripts"
PEER = "taichi-mls"  # the Taichi peer's rows in study_error.csv


def run_script(name: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    env.setdefault("NUMBA_CACHE_DIR", str(REPO / ".numba_cache"))
    result = run_in_group([sys.executable, str(SCRIPTS / name), *args], cwd=REPO, env=env,
                          timeout=timeout)
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


@pytest.mark.needs_tool
def test_study_error_smoke(tmp_path):
    png = tmp_path / "study_error.png"
    result = run_script("study_error.py", "--smoke", "--out-dir", str(tmp_path), "--png",
                        str(png))
    rows = list(csv.DictReader(open(tmp_path / "study_error.csv")))
    hpcmpm = [r for r in rows if r["transfer"] != PEER]
    assert {r["problem"] for r in hpcmpm} == {"bar", "mms"}
    assert {r["transfer"] for r in hpcmpm} == {"pic", "flip", "apic", "mls"}
    assert {r["kernel"] for r in hpcmpm} == {"quadratic", "cubic"}
    for r in rows:
        for key in ("dx", "error", "wall_s", "order"):
            assert math.isfinite(float(r[key])), (key, r)
        assert float(r["error"]) >= 0.0
    assert png.stat().st_size > 1000
    peer = [r for r in rows if r["transfer"] == PEER]
    if importlib.util.find_spec("taichi") is None:
        assert not peer
        assert f"peer ({PEER}) skipped: taichi not importable" in result.stdout
        # The rest passed; the strongest check is not made, and the report says so.
        pytest.skip("the Taichi peer's agreement to 1e-9 (check_peer_rows) needs taichi "
                    "(pip install -e '.[bench]')")
    check_peer_rows(peer, hpcmpm)


def check_peer_rows(peer, hpcmpm):
    """The peer's bar rows against hpcmpm's MLS/quadratic bar rows at the same resolutions.

    The peer (scripts/peer/mls_bar.py) solves the same discrete problem: the same particles,
    B-spline, MLS transfer, linear elastic stress, walls and CFL time-step rule. The two codes
    differ only in the order of their floating-point sums, so the step counts must be equal
    and the periods agree to round-off (measured: 1e-14 relative at 25 and 50 cells). The
    tolerance 1e-9 leaves five orders of magnitude for round-off and is still six orders
    below the period error itself (4e-3 to 7e-3 at these sizes), so any difference in the
    scheme (a stencil, wall or time-step rule not hpcmpm's) fails it."""
    mls = {r["cells"]: r for r in hpcmpm
           if (r["problem"], r["transfer"], r["kernel"]) == ("bar", "mls", "quadratic")}
    assert peer and {r["cells"] for r in peer} == set(mls)
    for r in peer:
        assert (r["problem"], r["kernel"]) == ("bar", "quadratic")
        ref = mls[r["cells"]]
        assert int(r["steps"]) == int(ref["steps"]) > 0
        # Relative period errors e = |P - T| / T of one sign, so |e - e_ref| = |P - P_ref| / T.
        assert abs(float(r["error"]) - float(ref["error"])) < 1e-9, (r, ref)
        assert 0.0 < float(r["error"]) < 0.02  # first order: 7.4e-3 at 25 cells


def test_study_error_without_taichi(tmp_path):
    """Without Taichi the study leaves the peer out, says why, and still writes its outputs."""
    blocked = (f"import runpy, sys; sys.modules['taichi'] = None; "
               f"sys.argv = ['study_error.py', '--smoke', '--problems', 'bar', '--out-dir', "
               f"{str(tmp_path)!r}, '--png', {str(tmp_path / 'p.png')!r}]; "
               f"runpy.run_path({str(SCRIPTS / 'study_error.py')!r}, run_name='__main__')")
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    env.setdefault("NUMBA_CACHE_DIR", str(REPO / ".numba_cache"))
    result = run_in_group([sys.executable, "-c", blocked], cwd=REPO, env=env, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert f"peer ({PEER}) skipped: taichi not importable" in result.stdout
    rows = list(csv.DictReader(open(tmp_path / "study_error.csv")))
    assert rows and {r["problem"] for r in rows} == {"bar"}
    assert PEER not in {r["transfer"] for r in rows}


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


def test_fuzz_scenes_smoke():
    """scripts/fuzz_scenes.py: a few hundred validations and two runs of mutated scenes give
    verdicts and no failure (the campaigns of stop 38 ran 280 000 and 2 113)."""
    out = run_script("fuzz_scenes.py", "validate", "--count", "300", "--seed", "4",
                     "--depth", "2").stdout
    assert out.startswith("validate: 300 verdicts") and "0 failure(s)" in out, out
    out = run_script("fuzz_scenes.py", "run", "--count", "2", "--seed", "5", "--scenes",
                     "bar_2d", "disks_2d").stdout
    assert out.startswith("run: 2 verdicts") and "0 failure(s)" in out, out


def test_study_multigrid_smoke(tmp_path):
    """scripts/study_multigrid.py on a small sponge's first solve: the system it assembles by
    probing is the solver's (the product on a random vector to round-off; Jacobi PCG on it
    stops within an iteration or two of the solver's own count: the two sum their dots in
    different orders, and a residual within round-off of the stop can fall either side of
    it), and geometric multigrid with each smoother, smoothed aggregation with Gauss-Seidel,
    the two-level and the patch (additive Schwarz) preconditioners converge in fewer
    iterations than Jacobi (a wrong prolongation or smoother would not; smoothed
    aggregation with damped Jacobi does not beat it at this size, 6 coarse unknowns, nor
    does it on the scenes: BENCHMARKS.md)."""
    out = tmp_path / "multigrid.json"
    run_script("study_multigrid.py", "--smoke", "--json", str(out))
    (row,) = json.loads(out.read_text())
    assert row["assembly_check"] < 1e-12 and row["symmetry"] < 1e-12, row
    assert abs(row["jacobi_iterations"] - row["solver_iterations"]) <= 2, row
    multigrid = {k: v for k, v in row.items()
                 if k.startswith(("geometric_", "aggregation_", "two_level_", "additive_"))}
    assert set(multigrid) >= {"additive_schwarz", "two_level_balancing", "geometric_jacobi_nu1",
                              "geometric_chebyshev_nu2",
                              "geometric_gauss_seidel_nu1", "aggregation_gauss_seidel_nu1"}
    for name, result in multigrid.items():
        if not name.startswith("aggregation_jacobi"):
            assert result["iterations"] < row["jacobi_iterations"], (name, row)
        assert result["work_per_iteration"] > 1.0, (name, row)
        if name != "additive_schwarz":  # one level: patches, no coarse space
            assert len(result["levels"]) >= 2, (name, row)


@pytest.mark.parametrize("d", [2, 3])
def test_study_multigrid_interpolation_is_exact_for_linear_fields(d):
    """The study's prolongation (multilinear, from the lattice of twice the spacing) carries
    any linear field on the coarse nodes to the same field on the fine ones, on a ragged set
    of fine nodes as a body's unknowns are: the property that makes the coarse levels
    represent smooth errors."""
    spec = importlib.util.spec_from_file_location("study_multigrid",
                                                  SCRIPTS / "study_multigrid.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    rng = np.random.default_rng(d)
    lattice = np.stack(np.meshgrid(*[np.arange(9)] * d, indexing="ij"), -1).reshape(-1, d)
    index = lattice[rng.random(len(lattice)) < 0.6]
    T, coarse = study.interpolation(index, d)
    slope, offset = rng.standard_normal(d), rng.standard_normal()
    fine = T @ (2 * coarse @ slope + offset)
    assert np.allclose(fine, index @ slope + offset, rtol=0, atol=1e-12)
    assert np.allclose(np.asarray(T.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)

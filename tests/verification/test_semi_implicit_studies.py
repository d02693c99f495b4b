"""Smoke runs of the semi-implicit studies at tiny sizes (their full runs and numbers are in
the report and docs): the Weissenberg sweep of 000 Fig. 5.4 keeps its ordering even coarse,
and the stability study runs a pie impact window at 300x the explicit step."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import study_blob_weissenberg  # noqa: E402
import study_semi_implicit_stability  # noqa: E402


def test_settled_height_falls_with_the_weissenberg_number():
    """000 Fig. 5.4: smaller Wi, faster relaxation of b_E to I, more plastic flow, lower
    blob. Coarse (dx = 1/32) and short (t = 0.8): Wi = 10, 0.1, 0.01 still order strictly."""
    result = study_blob_weissenberg.study((10.0, 0.1, 0.01), 1 / 32, 0.8)
    heights = [result["runs"][k]["height"] for k in ("10.0", "0.1", "0.01")]
    assert heights[0] > heights[1] > heights[2], heights


def test_pie_impact_is_stable_far_above_the_explicit_step():
    """The pie's crust (c = 3162) bounds the explicit step at 1e-6; the semi-implicit step
    at 300x that (3e-4) goes through the first 15 ms of the impact (the cream reaches the box
    at t = 0.129) without an instability."""
    result = study_semi_implicit_stability.study("pie_2d", (300,), window=(0.125, 0.14, 3.0))
    assert result["runs"]["300"]["stable"], result["runs"]["300"]["reason"]
    assert result["runs"]["300"]["steps"] >= 40   # 15 ms at 3e-4: "stable" means it ran


def test_semi_implicit_benchmark_smoke():
    """scripts/bench_semi_implicit.py at its smoke sizes (a few steps), so the benchmark the
    BENCHMARKS.md speed-ups, CG counts and Hessian-product ratios come from does not rot: every
    section reports finite, positive times, and the product and its tangents are timed."""
    import math

    import bench_semi_implicit

    results = bench_semi_implicit.main(["all", "--smoke"])
    for name, row in results["speedup"].items():
        for integrator in ("explicit", "semi_implicit"):
            assert row[integrator]["wall_s"] > 0.0 and row[integrator]["steps"] > 0, name
        assert math.isfinite(row["observable_relative_difference"]), name
    assert set(results["cg"]) == set(bench_semi_implicit.CG_SCENES)
    for name, row in results["hessian"].items():
        assert row["hessian_product_s"] > 0.0 and row["tangent_s"] > 0.0, name
        assert math.isfinite(row["ratio"]) and math.isfinite(row["tangent_ratio"]), name


def test_step_dependence_study_smoke():
    """`bench_semi_implicit.py steps` (the observable against the fixed step, BENCHMARKS.md)
    at its smoke size: both integrators run, at the step asked for, to a finite observable."""
    import math

    import bench_semi_implicit

    results = bench_semi_implicit.main(["steps", "--smoke", "--dt", "5e-4"])
    runs = results["steps"]["toothpaste_3d"]["runs"]
    assert {r["integrator"] for r in runs} == {"explicit", "semi_implicit"}
    for r in runs:
        assert r["steps"] == 2 and math.isfinite(r["observable"]), r
        assert not r["above_bound"], r

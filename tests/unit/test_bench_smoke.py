"""Smoke runs of every benchmark script (tiny scenes, a few steps): each runs, writes its JSON,
and reports finite numbers. No timing is asserted; the real numbers are in BENCHMARKS.md."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from launch import run_in_group

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / "scripts"
HAS_TAICHI = importlib.util.find_spec("taichi") is not None
NO_TAICHI = "taichi not installed (pip install -e '.[bench]')"


def run_script(name: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    env.setdefault("NUMBA_CACHE_DIR", str(REPO / ".numba_cache"))
    result = run_in_group([sys.executable, str(SCRIPTS / name), *args], cwd=REPO, env=env,
                          timeout=timeout)
    assert result.returncode == 0, f"{name} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def numbers(obj):
    """Every int/float inside a JSON document."""
    if isinstance(obj, bool):
        return
    if isinstance(obj, (int, float)):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from numbers(v)


def load_finite(path: Path) -> dict:
    assert path.exists(), f"{path} not written"
    doc = json.loads(path.read_text())
    values = list(numbers(doc["results"] if "results" in doc else doc["runs"]))
    assert values and all(math.isfinite(v) for v in values)
    return doc


@pytest.mark.needs_tool
@pytest.mark.skipif(not HAS_TAICHI, reason=NO_TAICHI)
def test_peer_smoke(tmp_path):
    # What one launch does, all scenes in this one process (the separate launches and their
    # ranges are bench_common.run_launches, exercised by test_bench_command_dispatches).
    run_script("bench_peer.py", "--smoke", "--reps", "2", "--steps", "3", "--in-process",
               "--out", str(tmp_path))
    doc = load_finite(tmp_path / "peer.json")
    assert [r["scene"] for r in doc["results"]] == ["a", "a_fc", "b"]
    assert doc["machine"]["cpu_flags"] and doc["machine"]["cpu"]
    for r in doc["results"]:
        assert r["ratio_hpcmpm_over_peer_min"] > 0 and r["process_threads"] >= 1
        # Same particles, step and walls: the two codes must agree closely.
        assert r["max_position_difference_cells"] < 0.05


def test_ceiling_smoke(tmp_path):
    run_script("bench_ceiling.py", "--smoke", "--reps", "2", "--steps", "3", "--in-process",
               "--out", str(tmp_path))
    doc = load_finite(tmp_path / "ceiling.json")
    assert {r["scene"] for r in doc["results"]} == {"a", "a_fc", "b"}
    for r in doc["results"]:
        assert set(r["hpcmpm_phases_ms_per_step"]) >= {"sort", "stress", "p2g", "grid", "g2p"}


@pytest.mark.needs_tool
@pytest.mark.skipif(shutil.which("mpiexec", path=str(Path(sys.executable).parent)
                                 + os.pathsep + os.environ.get("PATH", "")) is None,
                    reason="mpiexec not found")
def test_parallel_smoke(tmp_path):
    run_script("bench_parallel.py", "--smoke", "--reps", "2", "--steps", "2", "--rounds", "1",
               "--timeout", "120", "--out", str(tmp_path), *([] if HAS_TAICHI else ["--no-peer"]))
    doc = load_finite(tmp_path / "parallel.json")
    assert {"hpcmpm_1", "hpcmpm_2"} <= set(doc["runs"])
    assert doc["runs"]["hpcmpm_2"]["particles_per_rank"][0] > 0
    assert 0 < doc["efficiency"]["hpcmpm"]["efficiency_median"]
    # The co-run baseline's halves are exactly the 2-rank run's shares.
    halves = doc["runs"]["hpcmpm_corun"]["particles_per_rank"]
    assert halves == doc["runs"]["hpcmpm_2"]["particles_per_rank"]
    assert sum(halves) == doc["particles"]
    assert 0 < doc["efficiency"]["hpcmpm_vs_corun"]["efficiency_median"]
    # The barrier-per-phase mode: every rank takes the same phases, so it must not hang, and
    # its phases are recorded for both rank counts.
    run_script("bench_parallel.py", "--smoke", "--reps", "2", "--steps", "2", "--rounds", "1",
               "--timeout", "120", "--out", str(tmp_path), "--no-peer", "--sync-phases")
    synced = load_finite(tmp_path / "parallel_sync_phases.json")
    assert synced["sync_phases"] is True
    assert {"p2g", "g2p", "halo", "migrate"} <= set(
        synced["runs"]["hpcmpm_2"]["phases_max_over_ranks_s"])


def test_memory_smoke(tmp_path):
    run_script("bench_memory.py", "--smoke", "--cases", "2d_elastic", "3d_snow", "--out",
               str(tmp_path))
    doc = load_finite(tmp_path / "memory.json")
    for r in doc["results"]:
        # Peak RSS of a few thousand particles is within the allocator's noise: only its
        # presence is checked here.
        assert r["nbytes_per_particle"] > 0 and "rss_bytes_per_particle" in r


def test_startup_smoke(tmp_path):
    run_script("bench_startup.py", "--smoke", "--scenes", "a", "--warm-runs", "1", "--out",
               str(tmp_path))
    doc = load_finite(tmp_path / "startup.json")
    r = doc["results"][0]
    assert 0 < r["warm_to_first_step_s"] and 0 < r["cold_to_first_step_s"]


def test_bench_command_dispatches(tmp_path):
    from types import SimpleNamespace

    from hpcmpm.bench import bench_command
    from hpcmpm.errors import HpcmpmError

    assert bench_command(SimpleNamespace(bench_args=["--help"])) == 0
    with pytest.raises(HpcmpmError, match="unknown benchmark"):
        bench_command(SimpleNamespace(bench_args=["nonsense"]))
    code = bench_command(SimpleNamespace(bench_args=[
        "ceiling", "--smoke", "--scene", "a", "--reps", "1", "--steps", "2", "--launches", "2",
        "--out", str(tmp_path)]))
    assert code == 0 and (tmp_path / "ceiling.json").exists()
    # Two separate launches of scene a: the ratio is reported as their range.
    r = json.loads((tmp_path / "ceiling.json").read_text())["results"][0]
    assert len(r["launches"]) == 2 and len(r["ratio_hpcmpm_over_ceiling_min_launches"]) == 2
    lo, hi = r["ratio_hpcmpm_over_ceiling_min_range"]
    assert 0 < lo <= hi


def test_launches_are_merged_into_ranges_per_scene():
    sys.path.insert(0, str(SCRIPTS))
    import bench_common as bc

    def doc(launch, ratios):
        return {"machine": {"cpu": "x", "launch": launch},
                "results": [{"scene": k, "ratio_x_min": v, "ms": 1.0} for k, v in ratios]}

    merged = bc.merge_launches([doc(0, [("a", 2.0), ("b", 5.0)]), doc(1, [("a", 1.5)]),
                                doc(2, [("a", 2.5), ("b", 4.0)])])
    a, b = merged["results"]
    assert merged["launch_count"] == 3 and merged["machine"]["launch"] == 2
    assert a["ratio_x_min_launches"] == [2.0, 1.5, 2.5] and a["ratio_x_min_range"] == [1.5, 2.5]
    assert b["ratio_x_min_range"] == [4.0, 5.0] and len(b["launches"]) == 2
    assert "ms_range" not in a  # times are not ratios: kept per launch only
    assert bc.range_text(a, "ratio_x_min") == "1.50-2.50 (3 launches)"


def test_scaling_model_smoke(tmp_path):
    """The weak-scaling model's counting part on a few ranks, and the model with its plot."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("scaling_model",
                                                  SCRIPTS / "scaling_model.py")
    scaling_model = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(scaling_model)  # in this process: no second interpreter start
    scaling_model.main(["geometry", "--max-ranks", "4", "--out", str(tmp_path)])
    geo = json.loads((tmp_path / "scaling_geometry.json").read_text())
    # Two ranks of a fully periodic lattice are each other's only neighbour; four are all
    # neighbours; every rank has ghost nodes beyond its box.
    by_p = {(r["P"], r["particles_per_rank"]): r for r in geo["rows"]}
    assert by_p[(2, 100000)]["neighbours_max"] == 1 and by_p[(4, 100000)]["neighbours_max"] == 3
    assert all(r["ghost_nodes_max"] > 0 and r["imbalance"] >= 1.0 for r in geo["rows"])
    plot = tmp_path / "model.png"
    scaling_model.main(["model", "--out", str(tmp_path), "--plot", str(plot)])
    model = json.loads((tmp_path / "scaling_model.json").read_text())
    assert plot.stat().st_size > 0
    for curve in model["curves"].values():
        assert curve["efficiency"][0] == 1.0 and 0 < min(curve["efficiency"]) <= 1.0

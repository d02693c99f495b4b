"""Plots of the benchmark results: bench_results/*.json -> docs/img/bench_*.png (small PNGs).

    python scripts/bench_plots.py [--results bench_results] [--out docs/img]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_common as bc  # noqa: E402

PHASES = ["sort", "stress", "p2g", "halo", "grid", "g2p", "migrate"]


def load(folder: Path, name: str) -> dict | None:
    path = folder / name
    return json.loads(path.read_text()) if path.exists() else None


def plot_throughput(plt, peer: dict | None, ceiling: dict | None, out: Path) -> Path | None:
    if not peer and not ceiling:
        return None
    scenes = [r["scene"] for r in (peer or ceiling)["results"]]
    series = {}
    if peer:
        by = {r["scene"]: r for r in peer["results"]}
        series["hpcmpm"] = [by[k]["hpcmpm"]["particle_steps_per_s_median"] / 1e6 for k in scenes]
        series["Taichi CPU (peer)"] = [by[k]["peer"]["particle_steps_per_s_median"] / 1e6
                                       for k in scenes]
    if ceiling:
        by = {r["scene"]: r for r in ceiling["results"]}
        series["fused numba (ceiling)"] = [
            by[k]["ceiling"]["particle_steps_per_s_median"] / 1e6 if k in by else 0.0
            for k in scenes]
    fig, ax = plt.subplots(figsize=(6, 3.4), dpi=100)
    width = 0.8 / len(series)
    for i, (name, vals) in enumerate(series.items()):
        xs = [j + (i - (len(series) - 1) / 2) * width for j in range(len(scenes))]
        ax.bar(xs, vals, width, label=name)
    ax.set_xticks(range(len(scenes)), scenes)
    ax.set_ylabel("M particle-steps / s (median)")
    ax.set_title("Throughput, 1 core, float64")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "bench_throughput.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_phases(plt, peer: dict | None, out: Path) -> Path | None:
    if not peer:
        return None
    results = peer["results"]
    fig, axes = plt.subplots(1, len(results), figsize=(2.2 * len(results) + 1, 3.4), dpi=100)
    axes = axes if len(results) > 1 else [axes]
    for ax, r in zip(axes, results):
        bottom = 0.0
        ph = r["hpcmpm_phases_ms_per_step"]
        for name in PHASES:
            if name in ph:
                ax.bar([0], [ph[name]], bottom=bottom, label=name)
                bottom += ph[name]
        ax.set_xticks([0], [r["scene"]])
        ax.set_ylabel("ms / step")
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.suptitle("hpcmpm phase times (1 rank)", fontsize=10)
    fig.tight_layout()
    path = out / "bench_phases.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_parallel(plt, par: dict | None, out: Path) -> Path | None:
    if not par:
        return None
    runs = par["runs"]
    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=100)
    for code, label in (("hpcmpm", "hpcmpm (MPI ranks)"), ("peer", "Taichi (threads)")):
        pts = [(k, runs[f"{code}_{k}"]["ms_per_step_median"]) for k in (1, 2)
               if f"{code}_{k}" in runs]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
    ax.set_xticks([1, 2])
    ax.set_xlabel("cores")
    ax.set_ylabel("ms / step (median)")
    ax.set_title(f"Scene {par['scene']}: {par['particles']} particles")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "bench_parallel.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default=str(bc.RESULTS))
    ap.add_argument("--out", default=str(bc.REPO / "docs" / "img"))
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder, out = Path(args.results), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    peer, ceiling = load(folder, "peer.json"), load(folder, "ceiling.json")
    made = [plot_throughput(plt, peer, ceiling, out), plot_phases(plt, peer, out),
            plot_parallel(plt, load(folder, "parallel.json"), out)]
    for path in made:
        if path:
            print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

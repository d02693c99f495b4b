"""Weak-scaling model of the explicit step: measured inputs, modelled step time at 1 .. 10^4 ranks.

Four parts (docs/parallel.md "Weak scaling"); each prints its numbers and writes them to
bench_results/scaling_<part>.json:

``geometry``  (counts, no MPI, deterministic): the recursive bisection of a uniform, fully
    periodic 3D lattice (every rank interior) with n particles per rank (2 per cell per axis)
    at P = 2 .. 512 ranks: the particle imbalance (max / mean), the neighbours per rank (the
    code's own `neighbour_ranks`) and the ghost nodes per rank (support box minus owned box),
    which set the halo bytes (4 doubles summed, 3 filled per ghost node).
``traffic``   (counts, MPI, oversubscribed): the same lattice through real steps with
    `Communicator.count_traffic`: messages and bytes per rank per step at 8 and 16 ranks for
    two block sizes, against the geometric halo of ``geometry``.
``latency``   (times, MPI, 2 ranks: noisy on a shared host): ping-pong of 8 B and 1 MiB, a
    neighbour all-to-all of 8 B, the step's 5-double allreduce, and the Python cost of one
    halo region (packing and unpacking, measured on one fully periodic rank: 26 self images).
``model``     the step time t(P) = imbalance(P) n t_c + t_halo(n, P) + t_coll(P) and the
    efficiency t(1) / t(P) for n = 1e5 and 1e6 particles per rank, P = 1 .. 10^4, with t_c
    from BENCHMARKS.md and the network either this machine's (``latency``) or an assumed
    InfiniBand-class cluster; plot docs/img/weak_scaling_model.png.

    python scripts/scaling_model.py geometry
    mpiexec -n 8 python scripts/scaling_model.py traffic   # and -n 16
    mpiexec -n 2 python scripts/scaling_model.py latency
    python scripts/scaling_model.py model
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))
OUT = REPO / "bench_results"

PER_CELL = 8            # particles per cell (2 per axis, 3D)
SUM_DOUBLES, FILL_DOUBLES = 4, 3   # mass + momentum summed, velocity filled, per ghost node
ROW_BYTES = 220         # fields of a 3D elastic particle (BENCHMARKS.md "Memory per particle")
T_PARTICLE = 191e-9     # s per particle-step, 1 core: scene b, 50.1 ms / 262144 (BENCHMARKS.md)
# Fraction of a rank's surface-layer particles that cross a face per step: a flow at
# |v| dt / dx = 0.1 (an assumption: a fast flow under the CFL limit).
CROSSING = 0.1
# An assumed InfiniBand-class cluster (stated as such, not measured here).
CLUSTER = {"latency_s": 2e-6, "bandwidth_Bps": 10e9, "allreduce_stage_s": 3e-6}


def save(name: str, payload: dict) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"scaling_{name}.json").write_text(json.dumps(payload, indent=1))
    print(f"wrote {OUT / f'scaling_{name}.json'}")


# -- geometry ----------------------------------------------------------------------------------
def lattice_side(cells: int) -> tuple[int, int, int]:
    """A near-cubic domain of about ``cells`` cells."""
    side = round(cells ** (1 / 3))
    return side, side, max(1, round(cells / side ** 2))


def decompose_uniform(P: int, per_rank: int) -> dict:
    from hpcmpm.parallel.decomposition import neighbour_ranks, recursive_bisection
    from hpcmpm.parallel.domain import GHOST_ABOVE, GHOST_BELOW, NEIGHBOUR_REACH

    shape = np.array(lattice_side(P * per_rank // PER_CELL), dtype=np.int64)
    grids = np.meshgrid(*[np.arange(n, dtype=np.int64) for n in shape], indexing="ij")
    cells = np.stack([g.ravel() for g in grids], axis=1)
    del grids
    boxes = recursive_bisection(cells, P, shape, lambda a: a, lambda a: a,
                                np.ones(3, dtype=bool))
    del cells
    size = np.prod(boxes[:, 1] - boxes[:, 0], axis=1)
    steps = [(0, -1, 1)] * 3
    shifts = np.array(list(itertools.product(*steps)), dtype=np.int64) * shape
    sample = range(P) if P <= 64 else np.linspace(0, P - 1, 64).astype(int)
    neighbours = [len(neighbour_ranks(boxes, r, shifts, NEIGHBOUR_REACH)) for r in sample]
    ext = boxes[:, 1] - boxes[:, 0]
    ghost = np.prod(ext + GHOST_BELOW + GHOST_ABOVE, axis=1) - size
    faces = 2 * (ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 0] * ext[:, 2])
    return {"P": P, "particles_per_rank": per_rank, "domain_cells": shape.tolist(),
            "imbalance": float(size.max() / size.mean()),
            "neighbours_mean": float(np.mean(neighbours)), "neighbours_max": int(max(neighbours)),
            "ghost_nodes_mean": float(ghost.mean()), "ghost_nodes_max": int(ghost.max()),
            "face_cells_max": int(faces.max())}


def geometry(args) -> None:
    rows = []
    for per_rank, top in ((100_000, args.max_ranks), (1_000_000, min(args.max_ranks, 64))):
        P = 2
        while P <= top:
            row = decompose_uniform(P, per_rank)
            rows.append(row)
            print(f"n={per_rank:>8} P={P:>4}: imbalance {row['imbalance']:.3f}, neighbours "
                  f"mean {row['neighbours_mean']:.1f} max {row['neighbours_max']}, ghost nodes "
                  f"mean {row['ghost_nodes_mean']:.0f} max {row['ghost_nodes_max']}")
            P *= 2
    save("geometry", {"rows": rows})


# -- traffic -----------------------------------------------------------------------------------
TRAFFIC_SCENE = """
[simulation]
dim = 3
domain = {{ lower = [0.0, 0.0, 0.0], upper = [{lx}, {ly}, {lz}] }}
dx = 1.0
particles_per_cell = 2
periodic = ["x", "y", "z"]
dt = 0.02
end_time = {end}

[parallel]
rebalance_every = 1000

[[materials]]
name = "m"
type = "neo_hookean"
density = 1.0
E = 1.0
nu = 0.3

[[bodies]]
material = "m"
shape = "box"
lower = [0.0, 0.0, 0.0]
upper = [{lx}, {ly}, {lz}]
velocity = [{vx}, 0.0, 0.0]
"""


def traffic(args) -> None:
    from hpcmpm.parallel import Communicator
    from hpcmpm.runner import RunOptions, Runner, initial_particles, make_domain
    from hpcmpm.scene import parse_scene
    from hpcmpm.simulation import Simulation

    comm = Communicator()
    rows = []
    for per_rank in args.per_rank:
        lx, ly, lz = lattice_side(comm.size * per_rank // PER_CELL)
        steps = 6
        # |v| dt / dx = CROSSING: the particles near the faces cross at the modelled rate.
        scene = parse_scene(TRAFFIC_SCENE.format(lx=lx, ly=ly, lz=lz, end=steps * 0.02,
                                                 vx=CROSSING / 0.02))
        sim = Simulation(scene, make_domain(scene, comm))
        initial_particles(sim)
        traffic_counts = sim.domain.count_traffic()
        seen = []

        def record(s):
            seen.append(dict(traffic_counts.as_dict(), block=int(np.prod(s.grid.shape))))
            traffic_counts.reset()

        Runner(sim, None, RunOptions(out_dir=Path("."), end_time=scene.end_time, quiet=True),
               observer=record).run()
        per_step = seen[1:-1]  # the first builds the graph, the last is a frame step
        mine = {k: float(np.mean([s[k] for s in per_step]))
                for k in ("messages", "bytes", "collectives", "collective_bytes")}
        mine["neighbours"] = len(sim.domain.neighbours)
        box = sim.domain.boxes[sim.domain.rank]
        ext = box[1] - box[0]
        mine["ghost_nodes"] = float(np.prod(ext + 3) - np.prod(ext))
        table = comm.gather(mine)
        if comm.rank == 0:
            keys = list(mine)
            mean = {k: float(np.mean([t[k] for t in table])) for k in keys}
            top = {k: float(np.max([t[k] for t in table])) for k in keys}
            halo = mean["ghost_nodes"] * (SUM_DOUBLES + FILL_DOUBLES) * 8
            rows.append({"P": comm.size, "particles_per_rank": per_rank, "mean": mean,
                         "max": top, "geometric_halo_bytes": halo})
            print(f"P={comm.size} n={per_rank}: messages {mean['messages']:.1f} (max "
                  f"{top['messages']:.0f}), bytes {mean['bytes']:.0f} (max {top['bytes']:.0f}), "
                  f"geometric halo {halo:.0f} B, neighbours {mean['neighbours']:.1f}, "
                  f"collectives {mean['collectives']:.2f} of {mean['collective_bytes']:.0f} B")
    if comm.rank == 0:
        save(f"traffic_{comm.size}", {"rows": rows})


# -- latency -----------------------------------------------------------------------------------
def median_time(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def latency(args) -> None:
    from mpi4py import MPI

    from hpcmpm.parallel import Domain

    comm = MPI.COMM_WORLD
    if comm.size != 2:
        raise SystemExit("run with mpiexec -n 2")
    other = 1 - comm.rank
    small, big = np.zeros(1), np.zeros(2**17)  # 8 B, 1 MiB

    def pingpong(buf):
        def run():
            for _ in range(100):
                if comm.rank == 0:
                    comm.Send(buf, dest=other)
                    comm.Recv(buf, source=other)
                else:
                    comm.Recv(buf, source=other)
                    comm.Send(buf, dest=other)
        return run

    domain = Domain(3, 1.0, np.zeros(3), np.full(3, 8.0))
    graph = domain._neighbour_graph()
    counts_out, counts_in = np.zeros(1, np.int64), np.zeros(1, np.int64)
    out = {}
    comm.Barrier()
    out["pingpong_8B_s"] = median_time(pingpong(small), args.reps) / 200
    comm.Barrier()
    out["pingpong_1MiB_s"] = median_time(pingpong(big), args.reps) / 200
    comm.Barrier()
    out["neighbor_alltoall_8B_s"] = median_time(
        lambda: [graph.Neighbor_alltoall(counts_out, counts_in) for _ in range(100)],
        args.reps) / 100
    comm.Barrier()
    out["agree_allreduce_s"] = median_time(
        lambda: [domain.max_then_sum([1.0, 0.0, 0.0], [0.0]) for _ in range(100)],
        args.reps) / 100
    out["bandwidth_Bps"] = big.nbytes / max(out["pingpong_1MiB_s"] - out["pingpong_8B_s"], 1e-9)
    if comm.rank == 0:
        out["region_python_s"] = region_overhead(args.reps)
        for k, v in out.items():
            print(f"{k}: {v:.3g}")
        save("latency", out)


def region_overhead(reps: int) -> float:
    """Python cost of one halo region: a fully periodic 3D domain on one rank has 26 image
    regions, copied (not sent) by `sum_ghosts_to_owners` and `fill_ghosts`; the time of both
    on a tiny block, divided by the 52 regions, is the per-region cost (packing, slicing,
    unpacking) that a message to a neighbour adds besides the network."""
    from mpi4py import MPI

    from hpcmpm.parallel import Domain
    from hpcmpm.state import SCALAR, VECTOR, GridBlock, ParticleSet

    domain = Domain(3, 1.0, np.zeros(3), np.full(3, 6.0), comm=MPI.COMM_SELF,
                    periodic=(0, 1, 2))
    p = ParticleSet(3)
    p.append({"x": np.random.default_rng(0).uniform(0, 6, size=(64, 3))})
    grid = GridBlock(3, 1.0, np.zeros(3))
    grid.declare("mass", SCALAR)
    grid.declare("momentum", VECTOR)
    grid.declare("velocity", VECTOR)
    grid.fit(*domain.grid_box(p))
    regions = sum(len(r) for _, r in domain._plan.to_owners)

    def both():
        for _ in range(20):
            domain.sum_ghosts_to_owners(grid, "mass", "momentum")
            domain.fill_ghosts(grid, "velocity")

    both()
    return median_time(both, reps) / 20 / (2 * regions)


# -- model -------------------------------------------------------------------------------------
def step_time(n: float, P: float, geo: dict, net: dict, region_s: float) -> dict:
    """Modelled seconds per step on P ranks with n particles each (see the module docstring)."""
    if P == 1:
        return {"compute": n * T_PARTICLE, "halo": 0.0, "collective": 0.0, "total":
                n * T_PARTICLE}
    imbalance, neighbours, ghost = geo["imbalance"], geo["neighbours"], geo["ghost"]
    face_cells = geo["face_cells"]
    compute = imbalance * n * T_PARTICLE
    # Particles within CROSSING cells of an outflow face leave (half the faces are outflow).
    leaving = CROSSING * PER_CELL * face_cells / 2
    bytes_ = ghost * (SUM_DOUBLES + FILL_DOUBLES) * 8 + leaving * ROW_BYTES + 56 * neighbours
    messages = 4 * neighbours  # supports, counts, sums, fill (+ particles where they cross)
    halo = messages * (net["latency_s"] + region_s) + bytes_ / net["bandwidth_Bps"]
    collective = 2 * net["allreduce_stage_s"] * math.log2(P)  # one agreement per step
    collective *= 1 + 1 / 20  # the imbalance check every 20 steps
    return {"compute": compute, "halo": halo, "collective": collective,
            "total": compute + halo + collective}


def geometry_at(rows: list[dict], n: int, P: float) -> dict:
    """The bisection's numbers at the computed P nearest to P. Beyond the computed range the
    worst computed values (an interior rank of a uniform lattice has about as many
    neighbours and ghost nodes at any P; the whole-cell imbalance depends on how the cells
    divide, so its worst case is kept)."""
    mine = [r for r in rows if r["particles_per_rank"] == n]
    if not mine:
        raise SystemExit(f"no geometry rows for n={n}: run `geometry` first")
    if P > max(r["P"] for r in mine):
        return {"imbalance": max(r["imbalance"] for r in mine),
                "neighbours": max(r["neighbours_mean"] for r in mine),
                "ghost": max(r["ghost_nodes_max"] for r in mine),
                "face_cells": max(r["face_cells_max"] for r in mine)}
    best = min(mine, key=lambda r: abs(math.log(r["P"]) - math.log(max(P, 2))))
    return {"imbalance": best["imbalance"], "neighbours": best["neighbours_mean"],
            "ghost": best["ghost_nodes_max"], "face_cells": best["face_cells_max"]}


def model(args) -> None:
    geo_rows = json.loads((OUT / "scaling_geometry.json").read_text())["rows"]
    nets = {"cluster (assumed)": CLUSTER}
    region_s = args.region_s
    if args.measured_network:
        # Only meaningful from a `latency` run on a quiet machine (on a shared, loaded host
        # the latencies are scheduler delays, not the network's).
        lat = json.loads((OUT / "scaling_latency.json").read_text())
        nets["this machine (measured)"] = {
            "latency_s": lat["pingpong_8B_s"], "bandwidth_Bps": lat["bandwidth_Bps"],
            "allreduce_stage_s": lat["agree_allreduce_s"]}
        region_s = lat["region_python_s"]
    ranks = np.unique(np.round(np.logspace(0, 4, 41)).astype(int))
    result = {"inputs": {"t_particle_s": T_PARTICLE, "region_python_s": region_s,
                         "crossing": CROSSING, "row_bytes": ROW_BYTES, "networks": nets},
              "curves": {}}
    for name, net in nets.items():
        for n in (100_000, 1_000_000):
            base = step_time(n, 1, {}, net, region_s)["total"]
            eff = []
            for P in ranks:
                t = step_time(n, P, geometry_at(geo_rows, n, P), net, region_s)
                eff.append(base / t["total"])
            result["curves"][f"{name}, n={n:.0e}"] = {"P": ranks.tolist(), "efficiency": eff}
            for P in (1000, 10000):
                t = step_time(n, P, geometry_at(geo_rows, n, P), net, region_s)
                print(f"{name}, n={n:.0e}, P={P}: efficiency {base / t['total']:.3f} "
                      f"(compute {1e3 * t['compute']:.2f} ms, halo {1e3 * t['halo']:.3f} ms, "
                      f"collective {1e3 * t['collective']:.3f} ms)")
                result[f"{name}, n={n:.0e}, P={P}"] = {k: v for k, v in t.items()} | {
                    "efficiency": base / t["total"]}
    save("model", result)
    plot(result, args.plot)


def plot(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, curve in result["curves"].items():
        ax.semilogx(curve["P"], curve["efficiency"], label=f"model: {label}",
                    ls="-" if "cluster" in label else "--")
    ax.axhline(1.0, color="0.6", lw=0.8)
    ax.set_ylim(0.0, 1.05)
    ax.set_xlabel("MPI ranks P (one core each)")
    ax.set_ylabel("weak-scaling efficiency t(1) / t(P)")
    ax.set_title("hpcmpm explicit step, 3D elastic, modelled (not measured beyond 2 ranks)",
                 fontsize=9)
    ax.annotate("Published, Uintah MPMICE (MPM + ICE), in the authors' words:\n"
                "'good scalability ... up to 49K processors' (Peterson, Wight, Berzins,\n"
                "Procedia Comput. Sci. 18, 2013); 'linear scaling up to 180K cores'\n"
                "(Peterson et al., XSEDE 2012). Their data points are not plotted here.",
                xy=(0.02, 0.05), xycoords="axes fraction", fontsize=7, color="0.25")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("part", choices=["geometry", "traffic", "latency", "model"])
    ap.add_argument("--max-ranks", type=int, default=512, help="geometry: largest P")
    ap.add_argument("--per-rank", type=int, nargs="*", default=[2000, 16000],
                    help="traffic: particles per rank")
    ap.add_argument("--reps", type=int, default=7, help="latency: repetitions")
    ap.add_argument("--region-s", type=float, default=20e-6,
                    help="model: Python seconds per halo message (packing, slicing, unpacking)")
    ap.add_argument("--measured-network", action="store_true",
                    help="model: also this machine's latency run (quiet machine only)")
    ap.add_argument("--plot", default=str(REPO / "docs" / "img" / "weak_scaling_model.png"))
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    args = ap.parse_args(argv)
    global OUT
    if args.out:
        OUT = Path(args.out)
    {"geometry": geometry, "traffic": traffic, "latency": latency, "model": model}[args.part](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

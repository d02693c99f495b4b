"""Parallel efficiency: scene b (3D cube, fixed corotated) on 1 and 2 MPI ranks.

Launches ``mpiexec -n 1`` and ``mpiexec -n 2`` (the virtual environment's mpiexec, else the one
on PATH) running this script as a worker, with NUMBA_NUM_THREADS=1 per rank, alternating the
launches (1, 2, 1, 2, ... for ``--rounds`` rounds); every launch times ``--reps`` repetitions of
``--steps`` steps after a warm-up. A repetition's time is the slowest rank's. Efficiency is
``t1 / (2 t2)`` from the per-step medians (and from the minima). Unless ``--no-peer``, the peer
(Taichi, CPU, float64) runs the same scene with 1 and 2 threads for comparison, in separate
processes. Every launch has a timeout (``--timeout`` seconds), so a deadlock fails the
benchmark instead of hanging it. Writes bench_results/parallel.json. With ``--sync-phases``
every rank meets at a barrier before each phase, so the phase times are each phase's own work
without the waiting for the slower rank (written to parallel_sync_phases.json; its step
times include the barriers and are not an efficiency).

Co-run baseline (``--corun``, on by default): two 1-rank runs started at the same moment,
each on the half of the particles one rank of the 2-rank run owns (the same bisection), with
no MPI between them. Their time (the slower of the two, per repetition) is what two ranks
can reach on this machine when the cores and the memory system are shared but nothing is
exchanged or waited for; ``t_corun / t2`` says how much of that the 2-rank run keeps, and
the phase tables of the three runs side by side say where the rest goes (compute phases
slower than in the co-run: particle order, block size; halo and migration: exchange and
waiting; load: the halves' particle counts).

    python scripts/bench_parallel.py --steps 10 --reps 5 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_common as bc  # noqa: E402

MARK = "BENCH_RESULT "


def mpiexec() -> str:
    local = Path(sys.executable).parent / "mpiexec"
    found = str(local) if local.exists() else shutil.which("mpiexec")
    if not found:
        raise SystemExit("mpiexec not found (install the mpich extra: pip install -e '.[mpich]')")
    return found


# -- workers -----------------------------------------------------------------------------------
def half_of(s, half: int):
    """Indices of the particles rank ``half`` owns in the 2-rank decomposition of ``s``
    (the same recursive bisection, computed in one process)."""
    import numpy as np

    from hpcmpm.parallel.decomposition import particle_cells, recursive_bisection
    from hpcmpm.scene import parse_scene

    scene = parse_scene(bc.hpcmpm_toml(s))
    lo, hi = np.asarray(scene.domain_lo), np.asarray(scene.domain_hi)
    n_cells = np.round((hi - lo) / scene.dx).astype(np.int64)
    cells = particle_cells(s.x0, lo, 1.0 / scene.dx)
    boxes = recursive_bisection(cells, 2, n_cells, lambda a: a, lambda a: a)
    inside = np.all((cells >= boxes[half, 0]) & (cells < boxes[half, 1]), axis=1)
    return np.flatnonzero(inside)


def hpcmpm_worker(args) -> None:
    from hpcmpm.parallel import Communicator

    comm = Communicator()
    s = bc.make_scene(args.scene, args.smoke)
    select = None if args.half is None else half_of(s, args.half)
    sim = bc.build_hpcmpm(s, comm, select)
    sim.sync_phases = args.sync_phases
    domain = sim.domain
    for _ in range(args.warmup):
        sim.step(s.dt)
    sim.timers.reset()
    seconds = []
    for _ in range(args.reps):
        domain.barrier()  # every rank starts the repetition together
        start = time.perf_counter()
        for _ in range(args.steps):
            sim.step(s.dt)
        seconds.append(domain.max(time.perf_counter() - start))
    phases = {k: domain.max(v) for k, v in sorted(sim.timers.seconds.items())}
    counts = domain.allgather(sim.particles.n)
    if domain.rank == 0:
        print(MARK + json.dumps({"seconds": seconds, "particles_per_rank": counts,
                                 "phases_max_over_ranks_s": phases}), flush=True)


def peer_worker(args) -> None:
    sys.path.insert(0, str(HERE / "peer"))
    import mls_mpm
    from bench_peer import make_peer

    mls_mpm.init(threads=args.threads)
    s = bc.make_scene(args.scene, args.smoke)
    peer = make_peer(s)
    for _ in range(args.warmup):
        peer.substep()
    mls_mpm.sync()
    seconds = []
    for _ in range(args.reps):
        start = time.perf_counter()
        for _ in range(args.steps):
            peer.substep()
        mls_mpm.sync()
        seconds.append(time.perf_counter() - start)
    print(MARK + json.dumps({"seconds": seconds}), flush=True)


# -- driver ------------------------------------------------------------------------------------
def launch(cmd: list[str], env: dict, timeout: float) -> dict:
    try:
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise SystemExit(f"timed out after {timeout:.0f} s: {' '.join(cmd)}") from None
    for line in out.stdout.splitlines():
        if line.startswith(MARK):
            return json.loads(line[len(MARK):])
    raise SystemExit(f"no result from {' '.join(cmd)} (exit {out.returncode}):\n"
                     f"{out.stdout[-3000:]}\n{out.stderr[-3000:]}")


def launch_corun(me: list[str], args, env: dict) -> list[dict]:
    """The two halves as plain 1-rank processes started together; both results."""
    cmds = [me + ["--worker", "hpcmpm", "--half", str(h)] + worker_args(args) for h in (0, 1)]
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for c in cmds]
    results = []
    for proc, cmd in zip(procs, cmds):
        try:
            out, err = proc.communicate(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            for p in procs:
                p.kill()
            raise SystemExit(f"timed out after {args.timeout:.0f} s: {' '.join(cmd)}") from None
        lines = [ln for ln in out.splitlines() if ln.startswith(MARK)]
        if not lines:
            raise SystemExit(f"no result from {' '.join(cmd)}:\n{out[-2000:]}\n{err[-2000:]}")
        results.append(json.loads(lines[-1][len(MARK):]))
    return results


def worker_args(args) -> list[str]:
    a = ["--scene", args.scene, "--steps", str(args.steps), "--reps", str(args.reps),
         "--warmup", str(args.warmup)]
    return a + (["--smoke"] if args.smoke else []) + (["--sync-phases"] if args.sync_phases else [])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="b", choices=["a", "a_fc", "b"])
    ap.add_argument("--steps", type=int, default=None, help="steps per repetition")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3,
                    help="alternating launches per rank count (the efficiency is reported as "
                         "its range over the rounds; default 3)")
    ap.add_argument("--smoke", action="store_true", help="tiny scene (tests)")
    ap.add_argument("--no-peer", action="store_true", help="skip the Taichi 1/2-thread runs")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per launch")
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    ap.add_argument("--sync-phases", action="store_true",
                    help="barrier before every phase: the phase times leave out waiting for "
                         "other ranks (the step times then include the barriers)")
    ap.add_argument("--no-corun", dest="corun", action="store_false",
                    help="skip the co-run baseline (two 1-rank half runs at once)")
    ap.add_argument("--half", type=int, choices=[0, 1], default=None, help=argparse.SUPPRESS)
    ap.add_argument("--worker", choices=["hpcmpm", "peer"], help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.steps is None:
        args.steps = 3 if args.smoke else (10 if args.scene == "b" else 200)
    if args.worker == "hpcmpm":
        hpcmpm_worker(args)
        return 0
    if args.worker == "peer":
        peer_worker(args)
        return 0

    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    from hpcmpm.numba_cache import source_fingerprint

    env.setdefault("NUMBA_CACHE_DIR", str(bc.REPO / ".numba_cache" / source_fingerprint()))
    me = [sys.executable, str(Path(__file__).resolve())]
    with_peer = not args.no_peer
    if with_peer:
        try:
            import taichi  # noqa: F401
        except ImportError:
            print("peer skipped: taichi not installed (pip install -e '.[bench]')")
            with_peer = False
    runs: dict[str, list] = {"hpcmpm_1": [], "hpcmpm_2": [], "hpcmpm_corun": [], "peer_1": [],
                             "peer_2": []}
    per_round: dict[str, list] = {k: [] for k in runs}  # each launch's own seconds
    extra: dict[str, dict] = {}
    for _ in range(args.rounds):
        if args.corun:
            halves = launch_corun(me, args, env)
            # A repetition of the co-run lasts as long as its slower half.
            runs["hpcmpm_corun"] += [max(a, b) for a, b in
                                     zip(halves[0]["seconds"], halves[1]["seconds"])]
            extra["hpcmpm_corun"] = {
                "particles_per_rank": [h["particles_per_rank"][0] for h in halves],
                "phases_max_over_ranks_s": {k: max(h["phases_max_over_ranks_s"].get(k, 0.0)
                                                   for h in halves)
                                            for k in halves[0]["phases_max_over_ranks_s"]}}
        for ranks in (1, 2):
            r = launch([mpiexec(), "-n", str(ranks)] + me + ["--worker", "hpcmpm"]
                       + worker_args(args), env, args.timeout)
            runs[f"hpcmpm_{ranks}"] += r["seconds"]
            per_round[f"hpcmpm_{ranks}"].append(r["seconds"])
            extra[f"hpcmpm_{ranks}"] = {k: v for k, v in r.items() if k != "seconds"}
            if with_peer:
                r = launch(me + ["--worker", "peer", "--threads", str(ranks)]
                           + worker_args(args), env, args.timeout)
                runs[f"peer_{ranks}"] += r["seconds"]
                per_round[f"peer_{ranks}"].append(r["seconds"])
    s = bc.make_scene(args.scene, args.smoke)
    summary = {k: bc.summarize(v, args.steps, s.n) for k, v in runs.items() if v}
    for k, info in extra.items():
        summary[k].update(info)
    eff = {}
    for code in ("hpcmpm", "peer"):
        if f"{code}_2" in summary:
            one, two = summary[f"{code}_1"], summary[f"{code}_2"]
            eff[code] = {
                "efficiency_median": one["ms_per_step_median"] / (2 * two["ms_per_step_median"]),
                "efficiency_min": one["ms_per_step_min"] / (2 * two["ms_per_step_min"])}
            # The same ratio for each round's pair of launches (1 rank, then 2): its range
            # over the rounds is what the page reports (one launch's figure moves with the host).
            rounds = [statistics.median(a) / (2 * statistics.median(b)) for a, b in
                      zip(per_round[f"{code}_1"], per_round[f"{code}_2"])]
            eff[code]["efficiency_median_launches"] = rounds
            eff[code]["efficiency_median_range"] = [min(rounds), max(rounds)]
    if "hpcmpm_corun" in summary and "hpcmpm_2" in summary:
        corun, two = summary["hpcmpm_corun"], summary["hpcmpm_2"]
        eff["hpcmpm_vs_corun"] = {
            "efficiency_median": corun["ms_per_step_median"] / two["ms_per_step_median"],
            "efficiency_min": corun["ms_per_step_min"] / two["ms_per_step_min"]}
    rows = [[k, v["ms_per_step_min"], v["ms_per_step_median"],
             v["particle_steps_per_s_median"] / 1e6] for k, v in summary.items()]
    bc.print_table(["run", "ms/step min", "median", "Mpart-steps/s (median)"], rows)
    for code, e in eff.items():
        what = "t_corun / t2" if code.endswith("corun") else "t1/(2 t2)"
        spread = ""
        if "efficiency_median_range" in e:
            lo, hi = e["efficiency_median_range"]
            spread = (f"; per round {lo:.3f}-{hi:.3f} over "
                      f"{len(e['efficiency_median_launches'])} rounds")
        print(f"{code}: 2-rank efficiency {what} = {e['efficiency_median']:.3f} (median), "
              f"{e['efficiency_min']:.3f} (min){spread}")
    for k in ("hpcmpm_1", "hpcmpm_corun", "hpcmpm_2"):
        ph = summary.get(k, {}).get("phases_max_over_ranks_s")
        if ph:
            steps = args.steps * args.reps
            print(f"{k} phases (ms/step, slowest rank, last launch): " + ", ".join(
                f"{name} {1e3 * sec / steps:.2f}" for name, sec in ph.items()))
    if args.sync_phases:
        print("(--sync-phases: the step times include a barrier per phase; quote the phase "
              "times, not this efficiency)")
    name = "parallel_sync_phases.json" if args.sync_phases else "parallel.json"
    path = bc.write_json(name, {
        "machine": bc.machine_info(), "scene": args.scene, "particles": s.n,
        "steps_per_rep": args.steps, "rounds": args.rounds, "runs": summary,
        "efficiency": eff, "sync_phases": args.sync_phases}, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""2-rank step time and per-rank busy-time imbalance of a PD + MPM scene, with and without
the bond weights of the load balance (hpcmpm/pd/load.py, `Simulation.load_weights`).

The scene is the tearing PMB plate of inputs/pd_plate_tear_2d.toml (off the grid, 003 Alg. 2)
with a neo-Hookean block of about the same particle count beside it (the scene of
tests/mpi/test_pd_load_balance.py), at grid spacing ``--dx``; the bodies' extent is longest
along x, so 2 ranks cut x. ``--unweighted`` makes `Simulation.load_weights` return None: the
start-up decomposition and the run's rebalancing (every 20 steps, threshold 1.1) then split by
particle count, as before the weights existed.

Every phase starts with a barrier (`Simulation.sync_phases`) and the phase timers count the
process's CPU time (`CPUPhaseTimers`), so a rank's timers hold its own work, neither the
waiting for the other rank at the barrier nor the time the shared machine gives other
processes: busy time = the sum of its phase timers, busy imbalance = max / mean busy time over
ranks. What waiting remains inside a phase for a message is polled and counts, and on an
oversubscribed machine the partner may be descheduled meanwhile: so the script also prints the
compute time, the busy time without the message phases (``halo``: the grid ghost sum and
fill, ``migrate``), which is what a step on dedicated cores waits for (the PD phase still
holds its halo refresh).
Step time = wall time of the timed steps (after ``--warmup`` steps) / steps, max over ranks
(the barriers add a few us per phase, in both variants).

    mpiexec -n 2 python scripts/bench_pd_balance.py [--unweighted] [--dx 0.01] [--steps 200]
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from hpcmpm.parallel import Communicator
from hpcmpm.runner import RunOptions, Runner, initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation
from hpcmpm.timers import PhaseTimers

BLOCK = """
[[materials]]
name = "block"
type = "neo_hookean"
density = 2500.0
E = 7.2e10
nu = 0.25

[[bodies]]
name = "block"
material = "block"
shape = "box"
lower = [0.71, 0.25]
upper = [0.99, 0.75]
velocity = [0.0, 5.0]

[parallel]
rebalance_threshold = 1.1
rebalance_every = {rebalance_every}

[walls]"""


def scene_text(dx: float, end_time: float, rebalance_every: int = 20,
               dt: float | None = None) -> str:
    """The plate and the block (also the scene of tests/mpi/test_pd_load_balance.py); a fixed
    ``dt`` when given, else the CFL step."""
    text = open("inputs/pd_plate_tear_2d.toml").read()
    # Whole lines, whatever the scene's values: its spacing, end time and frame interval.
    text = text.replace("[walls]", BLOCK.format(rebalance_every=rebalance_every))
    for key, value in (("dx", dx), ("end_time", end_time), ("every", 1.0)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    if dt is not None:
        text = text.replace(f"end_time = {end_time}", f"end_time = {end_time}\ndt = {dt}")
    return text


MESSAGE_PHASES = ("halo", "migrate")


class CPUPhaseTimers(PhaseTimers):
    """PhaseTimers counting the process's CPU time (every thread) instead of wall time."""

    def __enter__(self) -> None:
        self._start = time.process_time()

    def __exit__(self, *exc) -> None:
        phase = self._phase
        self.seconds[phase] = self.seconds.get(phase, 0.0) + time.process_time() - self._start
        self.calls[phase] = self.calls.get(phase, 0) + 1


class _Done(Exception):
    """Ends the run after the timed steps."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dx", type=float, default=0.01)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--unweighted", action="store_true")
    args = ap.parse_args()
    scene = parse_scene(scene_text(args.dx, 1.0), path="pd_balance.toml")
    comm = Communicator()
    sim = Simulation(scene, make_domain(scene, comm))
    if args.unweighted:
        sim.load_weights = lambda: None
    sim.sync_phases = True
    sim.timers = CPUPhaseTimers()
    initial_particles(sim)
    total = args.warmup + args.steps
    clock = {}

    def observe(s) -> None:
        if s.step_index == args.warmup:
            s.domain.barrier()
            s.timers.reset()
            clock["start"] = time.perf_counter()
        if s.step_index == total:
            clock["stop"] = time.perf_counter()
            clock["end_time"] = s.time
            raise _Done

    with TemporaryDirectory() as tmp:
        runner = Runner(sim, None, RunOptions(out_dir=Path(tmp), end_time=1.0, quiet=True),
                        observer=observe)
        try:
            runner.run()
        except _Done:
            pass
    d = sim.domain
    step = d.max((clock["stop"] - clock["start"]) / args.steps)
    busy = np.array(d.allgather(sim.timers.total() / args.steps))
    compute = np.array(d.allgather(sum(t for k, t in sim.timers.seconds.items()
                                       if k not in MESSAGE_PHASES) / args.steps))
    counts = np.array(d.allgather(sim.particles.n))
    weights = sim.__class__.load_weights(sim)
    loads = np.array(d.allgather(int(weights.sum())))
    pd_counts = np.array(d.allgather(int(np.sum(sim.particles["group"] == 0))))
    phases = d.allgather(sim.timers.report())
    if d.rank == 0:
        print(f"{'unweighted' if args.unweighted else 'weighted'}: dx {args.dx}, "
              f"{counts.sum()} particles ({pd_counts.sum()} PD), {args.steps} steps: "
              f"step {step * 1e3:.2f} ms, busy per rank {np.round(busy * 1e3, 2)} ms "
              f"(imbalance {busy.max() / busy.mean():.3f}), compute per rank "
              f"{np.round(compute * 1e3, 2)} ms (imbalance {compute.max() / compute.mean():.3f}), "
              f"particles {counts} "
              f"(PD {pd_counts}), weight imbalance {loads.max() / loads.mean():.3f}")
        for r, text in enumerate(phases):
            print(f"  rank {r}: {text}")


if __name__ == "__main__":
    main()

"""What a step costs in communication, counted (`Communicator.count_traffic`) on 2 to 16
(oversubscribed) ranks: point-to-point messages and bytes per rank are bounded by the rank's
neighbour count and its own grid block and particles, not by the rank count; the step's
global collectives are at most two (the health/time-step agreement, and the imbalance check
on rebalance steps), each of a few doubles."""

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.runner import RunOptions, Runner, initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

STEPS, DT = 9, 4e-3
SCENE = f"""
[simulation]
dim = 3
domain = {{ lower = [0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }}
dx = 0.0625
particles_per_cell = 2
dt = {DT}
end_time = {STEPS * DT}

[parallel]
rebalance_every = 5
rebalance_threshold = 100.0  # checked, never taken: a rebalance is a rare, global event

[[materials]]
name = "jelly"
type = "neo_hookean"
density = 1000.0
E = 1e4
nu = 0.3

[[bodies]]
material = "jelly"
shape = "box"
lower = [0.2, 0.2, 0.2]
upper = [0.8, 0.8, 0.8]
angular_velocity = [0.0, 0.0, 3.0]
velocity = [0.3, 0.0, 0.0]
"""
# Messages a rank sends a neighbour in one step: support boxes (neighbour all-gather), the
# migration counts (neighbour all-to-all), ghost sums, ghost fill, migrating particles.
MESSAGES_PER_NEIGHBOUR = 5
# The largest global collective of a step: max_then_sum of 5 doubles (40 B).
COLLECTIVE_BYTES = 64


@pytest.mark.parallel(ranks=[2, 4, 8, 16])
def test_step_traffic_is_bounded_by_neighbours_and_halo_not_rank_count():
    comm = Communicator()
    scene = parse_scene(SCENE)
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    domain = sim.domain
    traffic = domain.count_traffic()
    steps = []

    def record(sim):
        grid = sim.grid
        steps.append(dict(traffic.as_dict(), neighbours=len(domain.neighbours),
                          block_nodes=int(np.prod(grid.shape)), particles=sim.particles.n))
        traffic.reset()

    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=scene.end_time, quiet=True),
           observer=record).run()
    assert len(steps) == STEPS
    row_bytes = sim.particles.nbytes_per_particle()
    doubles_per_node = 1 + 3 + 3  # mass + momentum summed, velocity filled
    for k, s in enumerate(steps[1:], start=2):  # step 1 also builds the neighbour graph
        assert s["collectives"] <= 2, (k, s)
        assert s["largest_collective"] <= COLLECTIVE_BYTES, (k, s)
        assert s["messages"] <= MESSAGES_PER_NEIGHBOUR * s["neighbours"], (k, s)
        # Ghost sums leave from my block, filled values from my owned nodes in it; the
        # migrating particles are some of mine; supports and counts 56 B per neighbour.
        bound = 8 * doubles_per_node * s["block_nodes"] + row_bytes * s["particles"] \
            + 56 * s["neighbours"]
        assert s["bytes"] <= bound, (k, s, bound)
    # One agreement per step; a second on the rebalance-check step (5) and on the frame step
    # (the last, 9: the state is checked again before it is written).
    assert [s["collectives"] for s in steps[1:]] == \
        [2 if k % 5 == 0 or k == STEPS else 1 for k in range(2, STEPS + 1)]
    summary = np.array([[np.mean([s[key] for s in steps[1:]]) for key in
                         ("messages", "bytes", "collectives", "collective_bytes")]
                        + [steps[-1]["neighbours"]]])
    table = comm.gather(summary)
    if comm.rank == 0:
        table = np.concatenate(table)
        print(f"\nTRAFFIC ranks={comm.size} per rank per step (mean over ranks, max): "
              f"messages {table[:, 0].mean():.1f} {table[:, 0].max():.1f}, bytes "
              f"{table[:, 1].mean():.0f} {table[:, 1].max():.0f}, collectives "
              f"{table[:, 2].mean():.2f}, collective bytes {table[:, 3].mean():.1f}, "
              f"neighbours {table[:, 4].mean():.1f} {table[:, 4].max():.0f}")

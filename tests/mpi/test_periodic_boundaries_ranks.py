"""Colliders and turning prescribed sets across a periodic face on several ranks
(hpcmpm/boundaries/colliders.py images, hpcmpm/boundaries/prescribed.py nearest image).

The one-process invariants are in tests/verification/test_collider_periodic.py (a disk on the
face acts as one inside; a turning set straddling the face moves as in a wide domain). Here
the same scenes run on N ranks, where the face lies between the last rank's box and the
first's: a node just beyond x = 1 on the last rank is node 0 of the first, and the collider's
image and the set's nearest-image offset must be taken on whichever rank holds the node. The
N-rank run must equal the 1-rank run up to the order of ghost sums."""

import numpy as np
import pytest
from mpi4py import MPI

from hpcmpm.parallel import Communicator
from hpcmpm.runner import simulate
from hpcmpm.scene import parse_scene
from mpi_helpers import gather_by_id
from periodic_layer_scenes import disk_in_flow, turning_set

DISK = disk_in_flow(0.0, max_dt=1e-3)   # the disk centred on the face x = 0
TURNING = turning_set(0.45, 0.55)       # longer in x than in y: the bisection cuts x


def run(text: str, comm) -> dict:
    scene = parse_scene(text, "scene.toml")
    sim = simulate(scene, scene.end_time, comm=Communicator(comm))
    if comm.size == 2:
        # The bodies are longer in x than in y, so the bisection cuts x: the periodic face
        # is where the last rank's box meets the first's, not inside one rank's box.
        boxes = sim.domain.boxes
        assert boxes[0, 1, 0] == boxes[1, 0, 0] and boxes[0, 0, 0] == 0
    return gather_by_id(sim.domain, sim.particles)


def against_one_rank(text: str) -> tuple[dict, dict]:
    got = run(text, MPI.COMM_WORLD)
    reference = run(text, MPI.COMM_SELF) if MPI.COMM_WORLD.rank == 0 else None
    return got, MPI.COMM_WORLD.bcast(reference)


@pytest.mark.parallel(ranks=[2])
def test_disk_on_a_periodic_face_between_ranks_matches_one_rank():
    """The disk centred on x = 0 is split by the face the ranks' boxes meet at: half of it
    acts through its image at x = 1 on the last rank."""
    got, reference = against_one_rank(DISK)
    np.testing.assert_array_equal(got["id"], reference["id"])
    v = got["v"]
    # The disk holds the layer back on both sides of the face: particles that start near
    # x = 0.9 (the last rank) and near x = 0.1 (the first) are slowed.
    assert np.abs(v[:, 0] - 1.0).max() > 0.5
    for name in ("x", "v", "F"):
        err = np.abs(got[name] - reference[name]).max() / np.abs(reference[name]).max()
        # Only the summation order of ghost contributions differs between rank counts
        # (as tests/mpi/test_periodic.py's block through the faces).
        assert err < 1e-10, (name, err)


@pytest.mark.parallel(ranks=[2])
def test_turning_set_across_a_periodic_face_between_ranks_matches_one_rank():
    """At t = 0.1 the set's centre is on x = 1: half its particles are wrapped to x < 0.1,
    owned by the first rank (the weighted bisection cuts at x = 0.9), and their nodes take
    the offset from the centre the short way round the period there."""
    got, reference = against_one_rank(TURNING)
    x = got["x"]
    assert (x[:, 0] < 0.5).any() and (x[:, 0] > 0.5).any()             # across the face
    assert np.abs(got["v"][:, 1]).max() > 0.2                           # it turns
    for name in ("x", "v", "F"):
        err = np.abs(got[name] - reference[name]).max() / np.abs(reference[name]).max()
        assert err < 1e-10, (name, err)

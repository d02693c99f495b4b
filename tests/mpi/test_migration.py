"""Migration: particles that cross a face, a corner (diagonal neighbour) or jump over whole
blocks arrive at their owner with every field intact (an extra tensor and an int field too),
and the global count is conserved."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from mpi_helpers import cloud, gather_by_id, particle_set, strided_share, with_fields_of_id


def moved_positions(ids, x, dim):
    """New positions, a function of id: a third of the particles take a small step (faces and
    corners), the rest jump anywhere, some beyond the walls (the outer boxes are unbounded)."""
    rng = np.random.default_rng(len(ids))
    jump = rng.uniform(-0.3, 1.3, size=x.shape)
    step = x + np.where((ids % 2)[:, None] == 0, 0.07, -0.07)
    return np.where((ids % 3 == 0)[:, None], step, jump)


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_every_field_arrives_by_id():
    # Both dimensions in one launch: an mpiexec start costs more than the checks.
    for dim in (2, 3):
        check_every_field_arrives_by_id(dim)


def check_every_field_arrives_by_id(dim):
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.ones(dim))
    values = cloud(dim, 1200, seed=11 + dim)
    # Start with everything on rank 0, as a serial reader would leave it, and move it the
    # way the start-up does, a bounded batch of rows per round (startup.MIGRATE_BATCH): 97
    # rows make 1200 particles take several rounds.
    p = particle_set(dim, values, None if domain.rank == 0 else np.arange(0))
    domain.decompose(p, batch=97)
    assert np.all(domain.owners(p["x"]) == domain.rank)

    old_owner = domain.owners(values["x"])
    moved = with_fields_of_id(values["id"], moved_positions(values["id"], values["x"], dim))
    new = _by_id(moved, p["id"])
    for name in p.field_names():
        p[name][...] = new[name]
    sent = domain.migrate_all(p)

    assert np.all(domain.owners(p["x"]) == domain.rank)
    assert domain.global_count(p) == len(values["id"])
    everything = gather_by_id(domain, p)
    for name in p.field_names():
        assert everything[name].dtype == moved[name].dtype, name
        np.testing.assert_array_equal(everything[name], moved[name], err_msg=name)
    # The moves really crossed faces, corners and several blocks: count them from the boxes.
    new_owner = domain.owners(moved["x"])
    assert domain.sum(sent) == int(np.sum(new_owner != old_owner))
    assert np.any(new_owner != old_owner) == (domain.size > 1)


def _by_id(values, ids):
    index = np.searchsorted(values["id"], ids)
    return {k: v[index] for k, v in values.items()}


@pytest.mark.parallel(ranks=[4])
def test_corner_and_far_jumps_in_a_2x2_split():
    # Both dimensions in one launch: an mpiexec start costs more than the checks.
    for dim in (2, 3):
        check_corner_and_far_jumps_in_a_2x2_split(dim)


def check_corner_and_far_jumps_in_a_2x2_split(dim):
    """In a 2x2 (x 1) split, each rank sends one particle to every other rank: to its face
    neighbours, to the diagonal one through the shared corner, and to the far side."""
    domain = Domain(dim, 1.0 / 8, np.zeros(dim), np.ones(dim))
    values = cloud(dim, 4000, seed=3)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    lo = domain.domain_lo + np.clip(domain.boxes[:, 0], 0, domain.n_cells) * domain.dx
    hi = domain.domain_lo + np.clip(domain.boxes[:, 1], 0, domain.n_cells) * domain.dx
    centres = 0.5 * (lo + hi)
    # Move one particle of mine into every other rank's box (just across the corner for the
    # diagonal neighbour: the corner point of the two boxes, nudged inside the target box).
    targets = [r for r in range(domain.size) if r != domain.rank]
    me = centres[domain.rank]
    for k, r in enumerate(targets):
        corner = np.where(centres[r] > me, lo[r], hi[r])
        p["x"][k] = np.where(np.isclose(centres[r], me), centres[r],
                             corner + 1e-3 * np.sign(centres[r] - me))
    moved_ids = domain.allgather(p["id"][:len(targets)].copy())
    sent = domain.migrate_all(p)
    assert sent == len(targets)
    arrived = set(p["id"].tolist())
    for r, ids in enumerate(moved_ids):
        if r != domain.rank:  # rank r sent its k-th particle to the k-th rank other than r
            assert ids[[q for q in range(domain.size) if q != r].index(domain.rank)] in arrived
    assert np.all(domain.owners(p["x"]) == domain.rank)
    assert domain.global_count(p) == len(values["id"])


@pytest.mark.parallel(ranks=[4])
def test_step_migration_defers_far_jumps_to_the_agreement():
    """The step's `migrate` talks to neighbours only: a particle that jumped past them stays
    (``pending_far``) until `agree`, the step's one global reduction, delivers it. A 4 x 1
    domain on 4 ranks makes 4 strips: the end strips are not neighbours."""
    dim = 2
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.array([4.0, 1.0]))
    values = cloud(dim, 2000, seed=17)
    values["x"][:, 0] *= 4.0
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    # A small step for everybody, and one particle per rank to the far end of the domain.
    p["x"][:] += 0.01
    p["x"][0] = [3.99, 0.99] if domain.rank != domain.size - 1 else [0.01, 0.01]
    domain.migrate(p)
    far_owner = domain.owners(p["x"][:1])[0]
    far = far_owner != domain.rank and far_owner not in domain.neighbours
    assert domain.pending_far == int(far)
    # The same reduction carries the step's largest speed, the broken-particle count and a
    # stop request (a signal that reached rank 1 only): every rank gets the global answers.
    domain.stop_requested = domain.rank == 1
    speed, broken = domain.agree(p, 0.5 * domain.rank, domain.rank % 2)
    assert speed == 0.5 * (domain.size - 1) and broken == domain.size // 2
    assert domain.stop_agreed is True and domain.pending_far == 0
    assert np.all(domain.owners(p["x"]) == domain.rank)
    assert domain.global_count(p) == len(values["id"])
    # 4 strips: ranks 0 and 1 jump past rank 2's neighbour set to rank 3, rank 3 to rank 0.
    assert domain.sum(int(far)) == 3
    # Each delivered particle counts once where it left and once where it arrived (the
    # health check re-sorts the particles of a rank whose count is nonzero).
    assert domain.sum(domain.moved_in_agree) == 2 * domain.sum(int(far))


@pytest.mark.parallel(ranks=[2])
def test_ranks_that_declared_fields_in_another_order_agree_on_the_records():
    """A particle travels as one packed record of all its fields (exchange.row_dtype); the
    fields are laid out by name, not in declaration order, so a rank whose ParticleSet
    declared its extra fields in another order reads the same bytes as the same fields."""
    from hpcmpm.state import ParticleSet
    from mpi_helpers import EXTRA_FIELDS

    dim = 2
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.ones(dim))
    values = cloud(dim, 300, seed=5)
    extra = dict(EXTRA_FIELDS) if domain.rank == 0 else dict(reversed(EXTRA_FIELDS.items()))
    p = ParticleSet(dim, extra)
    if domain.rank == 0:
        p.append(values)
    orders = domain.allgather(p.field_names())
    assert orders[0] != orders[1] and sorted(orders[0]) == sorted(orders[1])
    domain.decompose(p)
    everything = gather_by_id(domain, p)
    counts = domain.allgather(p.n)
    assert sum(counts) == 300 and counts[1] > 0  # rank 1 received records from rank 0
    for name in p.field_names():
        np.testing.assert_array_equal(everything[name], values[name], err_msg=name)

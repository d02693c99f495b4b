"""Load balance: a heap of particles on one side is badly balanced by an even split of the
domain; `rebalance` re-bisects by particle count and only moves particles."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from mpi_helpers import gather_by_id, particle_set, strided_share, with_fields_of_id


def heaped_cloud(dim, n, seed=7):
    """70 % of the particles in the slab x < 0.25, the rest spread over the whole box."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, size=(n, dim))
    heap = rng.uniform(size=n) < 0.7
    x[heap, 0] *= 0.25
    return with_fields_of_id(np.arange(n, dtype=np.int64) * 5 + 1, x)


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_rebalance_fixes_a_heap_and_only_moves_particles():
    dim = 2
    domain = Domain(dim, 1.0 / 64, np.zeros(dim), np.ones(dim))
    values = heaped_cloud(dim, 20000)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.migrate_all(p)  # the even split the constructor starts with
    before = domain.imbalance(p)
    counts = np.bincount(domain.owners(values["x"]), minlength=domain.size)
    assert before == pytest.approx(counts.max() / counts.mean(), rel=1e-15)
    assert (before > 1.2) == (domain.size > 1)
    snapshot = gather_by_id(domain, p)

    assert domain.rebalance(p, threshold=1.1) == (domain.size > 1)
    assert domain.imbalance(p) <= 1.1
    assert np.all(domain.owners(p["x"]) == domain.rank)
    after = gather_by_id(domain, p)
    for name in snapshot:
        np.testing.assert_array_equal(after[name], snapshot[name], err_msg=name)
    # Balanced now: a second call decides (on every rank alike) to do nothing.
    assert domain.rebalance(p, threshold=1.1) is False

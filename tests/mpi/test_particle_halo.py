"""Particle halo: a synthetic neighbour sum over all particles within r (own plus halo copies)
equals the one-process sum, particle by particle (by id)."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from mpi_helpers import cloud, particle_set, strided_share


def neighbour_sum(x_i, x_all, mass_all, r):
    """s_i = sum_{j : |x_i - x_j| < r} m_j exp(-|x_i - x_j|^2 / r^2)  (self included)."""
    d2 = ((x_i[:, None, :] - x_all[None, :, :]) ** 2).sum(axis=-1)
    return np.where(d2 < r * r, mass_all[None, :] * np.exp(-d2 / (r * r)), 0.0).sum(axis=1)


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_neighbour_sum_equals_one_process():
    for dim, n, dx, r in ((2, 900, 1.0 / 20, 0.08), (3, 500, 1.0 / 10, 0.17)):
        domain = Domain(dim, dx, np.zeros(dim), np.ones(dim))
        values = cloud(dim, n, seed=21 + dim)
        p = particle_set(dim, values, strided_share(values, domain))
        domain.decompose(p)
        halo = domain.particle_halo(p, r, ["id", "x", "mass"])

        assert set(halo) == {"id", "x", "mass"}
        assert halo["x"].shape == (len(halo["id"]), dim) and halo["id"].dtype == np.int64
        assert not set(halo["id"].tolist()) & set(p["id"].tolist())
        assert len(np.unique(halo["id"])) == len(halo["id"])
        x_all = np.concatenate([p["x"], halo["x"]])
        m_all = np.concatenate([p["mass"], halo["mass"]])
        mine = neighbour_sum(p["x"], x_all, m_all, r)

        index = np.searchsorted(values["id"], p["id"])
        reference = neighbour_sum(values["x"][index], values["x"], values["mass"], r)
        np.testing.assert_allclose(mine, reference, rtol=1e-12, atol=0)
        # The halo is what the owned region needs, not a copy of everything.
        assert len(halo["id"]) < len(values["id"]) - p.n or domain.size == 1

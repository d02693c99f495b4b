"""End to end through the real transfer kernels: a few explicit MPM steps (P2G, sum ghosts,
grid update, fill ghosts, G2P, migrate, and one rebalance) on N ranks give the 1-rank particles,
by id, to round-off. This checks the ghost widths against the kernels' actual stencils."""

import numpy as np
import pytest
from mpi4py import MPI

from hpcmpm.kernels.grid import update_velocity
from hpcmpm.kernels.shape import CUBIC, QUADRATIC, inverse_inertia_factor
from hpcmpm.kernels.transfer import APIC, GATHER, MLS, SCATTER, static
from hpcmpm.parallel import Domain
from hpcmpm.state import SCALAR, TENSOR, VECTOR, FieldSpec, GridBlock, ParticleSet

MU, LAM = 50.0, 80.0


def kirchhoff_neo_hookean(F):
    """tau = mu (F F^T - I) + lam ln(J) I."""
    dim = F.shape[-1]
    J = np.linalg.det(F)
    return MU * (F @ np.swapaxes(F, 1, 2) - np.eye(dim)) + LAM * np.log(J)[:, None, None] \
        * np.eye(dim)


def lattice(dim, n_per_axis):
    g = (np.arange(n_per_axis) + 0.5) / n_per_axis
    return np.stack(np.meshgrid(*[g] * dim, indexing="ij"), -1).reshape(-1, dim)


def two_blocks(dim, n_per_axis):
    """Two spinning blocks flying at each other. The second is sampled half as densely, so the
    first cut runs through the first block and its particles cross it."""
    a = 0.1 + 0.35 * lattice(dim, n_per_axis)
    b = 0.5 + 0.35 * lattice(dim, n_per_axis // 2)
    x = np.concatenate([a, b])
    centre = np.where(np.arange(len(x))[:, None] < len(a), 0.275, 0.675) * np.ones(dim)
    v = np.concatenate([np.full_like(a, 0.8), np.full_like(b, -0.8)])
    v[:, 0] += -3.0 * (x[:, 1] - centre[:, 1])
    v[:, 1] += 3.0 * (x[:, 0] - centre[:, 0])
    n = len(x)
    return {"id": np.arange(n, dtype=np.int64), "x": x, "v": v,
            "mass": np.full(n, 1.0 / n), "vol0": np.full(n, 1.0 / n)}


def run(domain, dim, values, scheme, order, steps, dt):
    p = ParticleSet(dim, {"C": FieldSpec(TENSOR), "tau": FieldSpec(TENSOR),
                          "F": FieldSpec(TENSOR, "f8", "identity")})
    mine = np.flatnonzero(values["id"] % domain.size == domain.rank)
    p.append({k: v[mine] for k, v in values.items()})
    domain.decompose(p)
    grid = GridBlock(dim, domain.dx, domain.domain_lo)
    grid.declare("mass", SCALAR)
    grid.declare("momentum", VECTOR)
    grid.declare("velocity", VECTOR)
    dinv_factor = inverse_inertia_factor(order)
    sent = 0
    for step in range(steps):
        p["tau"][...] = kirchhoff_neo_hookean(p["F"])
        grid.fit(*domain.grid_box(p, order))
        SCATTER[dim](p["x"], p["v"], p["C"], p["mass"], p["vol0"], p["tau"], static(scheme),
                     static(order), dinv_factor, domain.dx, domain.domain_lo, grid.origin, dt,
                     static(False), grid["mass"], grid["momentum"], grid["momentum"])
        domain.sum_ghosts_to_owners(grid, "mass", "momentum")
        velocity = grid["velocity"]
        update_velocity(grid["mass"].reshape(-1), grid["momentum"].reshape(-1, dim),
                        grid["momentum"].reshape(-1, dim), False, np.zeros(dim), dt,
                        velocity.reshape(-1, dim), velocity.reshape(-1, dim), False)
        domain.fill_ghosts(grid, "velocity")
        GATHER[dim](p["x"], p["v"], p["C"], p["F"], static(scheme), static(order), dinv_factor,
                    domain.dx, domain.domain_lo, grid.origin, dt, 0.0, velocity, velocity)
        sent += domain.migrate(p)
        if step == steps // 2:  # moving the cuts only moves particles
            domain.rebalance(p, threshold=1.0)
    parts = domain.allgather(p.snapshot())
    merged = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    order_ = np.argsort(merged["id"])
    return {k: v[order_] for k, v in merged.items()}, domain.sum(sent)


@pytest.mark.parallel(ranks=[2, 4])
def test_steps_on_n_ranks_equal_one_rank():
    for dim, scheme, order, n_axis, dx, steps in ((2, APIC, CUBIC, 24, 1.0 / 32, 12),
                                                  (3, MLS, QUADRATIC, 8, 1.0 / 16, 12)):
        world = Domain(dim, dx, np.zeros(dim), np.ones(dim))
        alone = Domain(dim, dx, np.zeros(dim), np.ones(dim), comm=MPI.COMM_SELF)
        values = two_blocks(dim, n_axis)
        dt = 0.03 * dx  # CFL: c = sqrt((lam + 2 mu) / rho) = 13.4
        reference, _ = run(alone, dim, values, scheme, order, steps, dt)
        result, migrated = run(world, dim, values, scheme, order, steps, dt)
        for name in ("id", "x", "v", "C", "F", "tau", "mass"):
            scale = np.abs(reference[name]).max()
            np.testing.assert_allclose(result[name], reference[name], rtol=0,
                                       atol=1e-11 * scale, err_msg=f"{dim}D {name}")
        # The run did cross ranks: every rank held particles and some changed rank.
        assert len(set(world.owners(values["x"]).tolist())) == world.size
        assert migrated > 0

"""The PD clamp's ghost store (hpcmpm/pd/clamp.py, `ghost_store`) travels with its particles:
a clamped, yielding bond-energy slab slides along its sticky floor across the ranks' cut, and
after every step each rank's store holds an entry for each ghost source of exactly the
particles within reach of the floor that it owns, in their row order; the run ends where the
1-rank run does."""

import numpy as np
import pytest
from mpi4py import MPI

from hpcmpm.parallel import Communicator
from hpcmpm.pd.clamp import near_rows
from hpcmpm.runner import RunOptions, Runner, initial_particles, make_domain
from hpcmpm.scene import load_scene
from hpcmpm.simulation import Simulation

DT, STEPS = 6e-5, 120
# tests/mpi/test_pd_models_engine.py's slab: inputs/ibmpm_wall_fracture_2d.toml's wall made
# low and sliding, so its ghost bonds at the floor yield and particles cross the cut (along x).
SETS = ["bodies.0.velocity=[4.0, 0.0]", "bodies.0.lower=[0.1, 0.0]",
        "bodies.0.upper=[0.9, 0.06]", f"simulation.dt={DT}"]


def run(comm, check=None):
    scene = load_scene("inputs/ibmpm_wall_fracture_2d.toml", SETS)
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    Runner(sim, None, RunOptions(out_dir=".", end_time=STEPS * DT, quiet=True),
           observer=check).run()
    return sim


def by_id(domain, p) -> dict:
    parts = domain.allgather({k: p[k].copy() for k in ("id", "x", "v")})
    merged = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    order = np.argsort(merged["id"])
    return {k: v[order] for k, v in merged.items()}


@pytest.mark.parallel(ranks=[2])
def test_ghost_store_follows_its_particles_across_ranks():
    comm = Communicator()
    seen = []

    def check(sim):
        ext = sim.extensions[0]
        # The step's migration moved particles; the sort and the side structures follow at
        # the next step's start (collective; what that step would do first).
        sim.ensure_grouped()
        start, stop = ext.prepare()
        assert np.array_equal(ext.bond_ids, sim.particles["id"][start:stop])
        near = near_rows(sim.particles["x0"][start:stop], stop - start,
                         ext.model.clamp_faces, ext.model.clamp)
        counts = ext.ghosts.counts()
        assert ext.ghosts.n == stop - start
        assert np.array_equal(counts, np.where(near, ext.bonds.counts() + 1, 0))
        seen.append((ext.redistributions, int(near.sum())))

    sim = run(comm, check)
    ext = sim.extensions[0]
    # Particles with ghosts changed rank during the run (the check is not vacuous), and
    # their ghost bonds yielded.
    assert ext.redistributions > 0 and all(n > 0 for _, n in seen)
    name = ext.model.ghost_states[0]
    assert sim.domain.sum(int(np.count_nonzero(ext.ghosts.state[name]))) > 100
    got = by_id(sim.domain, sim.particles)
    ref = None
    if comm.rank == 0:
        alone = run(Communicator(MPI.COMM_SELF))
        ref = by_id(alone.domain, alone.particles)
    ref = comm.comm.bcast(ref, root=0)
    assert np.array_equal(got["id"], ref["id"])
    for key in ("x", "v"):
        # Grid round-off only (the MPM sums run in another order on 2 ranks), as in
        # test_pd_models_engine's 1-against-2-rank check of the same slab.
        err = np.abs(got[key] - ref[key]).max() / np.abs(ref[key]).max()
        assert err < 1e-10, f"{key}: {err:.2e}"

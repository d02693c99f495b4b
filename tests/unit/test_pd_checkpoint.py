"""A PD scene's checkpoint written before the first step (a signal at once, or a checkpoint
at step 0) holds no bonds yet (``initialized = false`` in pd_bonds_<material>/): the restart
makes the families itself at its first step, as the uninterrupted run does, and reaches the
same state bitwise. Reading that empty checkpoint as bonds would leave every particle
without a bond."""

from pathlib import Path

import numpy as np

from hpcmpm.parallel import Communicator
from hpcmpm.runner import (RunOptions, Runner, initial_particles, make_domain,
                           restore_simulation)
from hpcmpm.scene import load_scene
from hpcmpm.simulation import Simulation

DT, STEPS = 1.2e-6, 30


def by_id(p) -> dict:
    order = np.argsort(p["id"])
    return {k: p[k][order].copy() for k in ("id", "x", "v", "damage")}


def test_restart_from_a_checkpoint_written_before_the_first_step(tmp_path):
    comm = Communicator()
    scene = load_scene("inputs/pd_plate_tear_2d.toml", [f"simulation.dt={DT}"])
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    runner = Runner(sim, None, RunOptions(out_dir=tmp_path / "a", end_time=STEPS * DT,
                                          quiet=True))
    runner.write_checkpoint()
    ckpt = runner.latest_checkpoint_path
    assert sim.step_index == 0 and sim.extensions[0].bonds is None
    runner.run()
    ref = by_id(sim.particles)

    again, meta, end = restore_simulation(str(ckpt), comm, STEPS * DT)
    assert meta["step"] == 0 and again.extensions[0].bonds is None
    Runner(again, None, RunOptions(out_dir=tmp_path / "b", end_time=end, quiet=True)).run()
    got = by_id(again.particles)
    assert again.step_index == STEPS
    # The plate moves (its bonds pull it back from the initial velocities).
    assert np.abs(ref["x"] - sim.particles["x0"][np.argsort(sim.particles["id"])]).max() > 0
    for name in ("id", "x", "v", "damage"):
        assert np.array_equal(got[name], ref[name]), name


def segments_by_id(ext) -> dict:
    """{(owner id, partner id): (weight, status, state values...)} of an extension's bonds."""
    b = ext.bonds
    owner = np.repeat(ext.bond_ids, b.counts())
    names = sorted(b.state)
    return {(int(o), int(q)): (w, int(s), *[b.state[k][i] for k in names])
            for i, (o, q, w, s) in enumerate(zip(owner, b.partner, b.weight, b.status))}


def test_restored_bonds_are_the_checkpointed_bonds(tmp_path):
    """Every half-bond of the restored run (owner, partner, weight, status, state) is the
    checkpointed run's, broken ones included. The restart test of the whole scene
    (tests/mpi/test_pd_restart.py) cannot see a broken bond restored as intact while it
    stays stretched past s0 (it breaks again before the forces read it): checked here
    directly. Measured: 1520 of 53000 half-bonds broken at step 40 (PMB: no per-bond state;
    tests/mpi/test_pd_models_engine.py restarts the models that keep one)."""
    comm = Communicator()
    scene = load_scene("inputs/pd_plate_tear_2d.toml", [f"simulation.dt={DT}"])
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    runner = Runner(sim, None, RunOptions(out_dir=tmp_path, end_time=40 * DT, quiet=True))
    runner.run()
    runner.write_checkpoint()
    ext = sim.extensions[0]
    want = segments_by_id(ext)
    assert sum(1 for v in want.values() if v[1] == 0) > 100

    again, _, _ = restore_simulation(str(runner.latest_checkpoint_path), comm, None)
    got = segments_by_id(again.extensions[0])
    assert got.keys() == want.keys()
    for key, value in want.items():
        assert got[key] == value, key


def test_restart_from_bonds_checkpointed_without_image_labels(tmp_path):
    """Bonds checkpointed before half-bonds carried periodic image labels (no
    ``particles/image`` in pd_bonds_<material>/) restart with every label 0, the minimum
    image, and reach the uninterrupted run's state bitwise."""
    import h5py

    from hpcmpm.pd.extension import bonds_folder

    comm = Communicator()
    scene = load_scene("inputs/pd_plate_tear_2d.toml", [f"simulation.dt={DT}"])
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    runner = Runner(sim, None, RunOptions(out_dir=tmp_path, end_time=20 * DT, quiet=True))
    runner.run()
    runner.write_checkpoint()
    ckpt = Path(runner.latest_checkpoint_path)
    Runner(sim, None, RunOptions(out_dir=tmp_path / "rest", end_time=STEPS * DT,
                                 quiet=True)).run()
    ref = by_id(sim.particles)
    with h5py.File(bonds_folder(ckpt.parent, "glass") / ckpt.name, "r+") as h5:
        del h5["particles/image"]
    again, _, end = restore_simulation(str(ckpt), comm, STEPS * DT)
    assert not again.extensions[0].bonds.image.any()
    Runner(again, None, RunOptions(out_dir=tmp_path / "b", end_time=end, quiet=True)).run()
    got = by_id(again.particles)
    assert again.step_index == STEPS
    for name in ("id", "x", "v", "damage"):
        assert np.array_equal(got[name], ref[name]), name

"""A peridynamic scene's bonds checkpoint with its particles: a run stopped at step 50 and
restarted on the same or another rank count reaches step 100 bitwise equal to the
uninterrupted run (integration = "pd" does not depend on the decomposition), broken bonds
included (damage, positions, and the broken bonds in the checkpoint file itself)."""

import h5py
import numpy as np
import pytest

from hpcmpm.io.checkpoint import latest_checkpoint
from launch import mpi_hpcmpm as hpcmpm
from scene_runs import last_frame

DT = 1.2e-6
FIXED = ["--set", f"simulation.dt={DT}", "--set", f"output.every={50 * DT}"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    full = tmp_path_factory.mktemp("full")
    hpcmpm(1, "run", "inputs/pd_plate_tear_2d.toml", "--out", str(full), "--quiet",
           "--end-time", str(100 * DT), *FIXED)
    return last_frame(full, 100, 1)


@pytest.mark.parametrize("first,second", [(2, 2), (1, 4)])
def test_pd_restart_is_bitwise(tmp_path, uninterrupted, first, second):
    ref = uninterrupted
    part = tmp_path / "part"
    hpcmpm(first, "run", "inputs/pd_plate_tear_2d.toml", "--out", str(part), "--quiet",
           "--end-time", str(50 * DT), *FIXED)
    ckpt = latest_checkpoint(part)
    assert ckpt.name == "ckpt_000000050.h5"
    assert (part / "pd_bonds_glass" / ckpt.name).exists()
    mid = last_frame(part, 50, first)
    assert mid["damage"].max() > 0          # bonds had broken before the checkpoint
    # The checkpoint holds the broken bonds themselves: a restart that lost them would go on
    # bitwise here all the same (a healed bond still stretched past s0 breaks again, with no
    # force, in its first step; a mutant that wrote every bond intact passed the comparison
    # below), so the particles with broken half-bonds in the file must be the damaged ones.
    with h5py.File(part / "pd_bonds_glass" / ckpt.name, "r") as f:
        owner, status = f["particles/owner"][:], f["particles/status"][:]
    assert np.array_equal(np.unique(owner[status == 0]), np.sort(mid["id"][mid["damage"] > 0]))
    hpcmpm(second, "restart", str(ckpt), "--end-time", str(100 * DT), "--quiet")
    got = last_frame(part, 100, second)
    assert np.array_equal(got["id"], ref["id"])
    for name in ("x", "v", "damage"):
        assert np.array_equal(got[name], ref[name]), name

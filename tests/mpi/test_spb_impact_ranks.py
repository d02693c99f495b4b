"""SPB-MPM with the shock model (deformation mode "L") on 1 (in process), 2 and 4
(oversubscribed) ranks: the watermelon scene, coarse (dx = 0.02, 1100 particles) with a fixed
dt so every rank count takes the same 100 steps, gives the same PD set and bitwise the same
damage, positions and velocities within 1e-10; the smallest relative distance of any G_i to
G_EE is reported (round-off between rank counts must stay below it); a restart on 2 ranks
from the half-way checkpoint is bitwise the uninterrupted run."""

from pathlib import Path

import numpy as np

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene
from launch import mpi_hpcmpm as hpcmpm
from scene_runs import last_frame, run_scene

SCENE = "inputs/watermelon_3d.toml"
DT, STEPS = 2e-6, 100
# G_EE raised for the coarse grid (l0 = delta doubles with dx): about a fifth converts.
SETS = ["simulation.dx=0.02", f"simulation.dt={DT}", f"simulation.end_time={DT * STEPS}",
        f"output.every={DT * STEPS}", "materials.flesh.failure.grid_energy=6e8",
        "materials.rind.failure.grid_energy=2.4e9"]


def final_frame(out: Path) -> dict:
    return last_frame(out, STEPS)


def run(ranks: int, out: Path, *extra) -> dict:
    # The coarse watermelon's fixed dt is past the CFL bound of its first steps (2e-6 against
    # 1.85e-6 at step 1, the runner warns); every rank count takes the same steps all the same.
    return run_scene(ranks, SCENE, SETS, out, STEPS, *extra, past_cfl=True)


def test_shock_spb_watermelon_matches_across_rank_counts(tmp_path):
    sim = simulate(load_scene(SCENE, SETS))
    ext = sim.extensions[0]
    margins = ext.margins(sim.domain)
    p = sim.particles
    order = np.argsort(p["id"])
    ref = {k: p[k][order] for k in ("id", "x", "v", "model", "damage", "J")}
    n_pd = int((ref["model"] == 1).sum())
    print(f"1 rank: PD {n_pd} of {len(order)}, damaged {int((ref['damage'] > 0).sum())}, "
          f"smallest margin G_i to G_EE {margins['flag']:.2e}")
    assert 0.05 * len(order) < n_pd < 0.9 * len(order)      # partly converted
    assert ref["damage"].max() > 0.3                         # and torn
    frames = {}
    for ranks in (2, 4):
        extra = ["--checkpoint-every", str(STEPS // 2)] if ranks == 2 else []
        got = frames[ranks] = run(ranks, tmp_path / f"n{ranks}", *extra)
        assert np.array_equal(got["id"], ref["id"])
        assert np.array_equal(got["model"], ref["model"]), f"{ranks} ranks: PD set"
        assert np.array_equal(got["damage"], ref["damage"]), f"{ranks} ranks: broken bonds"
        for name in ("x", "v", "J"):
            err = np.abs(got[name] - ref[name]).max() / np.abs(ref[name]).max()
            # Round-off from the grid's summation order, amplified over the steps.
            assert err < 1e-10, f"{ranks} ranks: {name} differs by {err:.2e}"

    # Restart on 2 ranks from the half-way checkpoint (PD particles, bonds, EE_p and the
    # shock state in it): bitwise the uninterrupted run.
    ckpt = tmp_path / "n2" / f"ckpt_{STEPS // 2:09d}.h5"
    assert ckpt.exists()
    hpcmpm(2, "restart", str(ckpt), "--out", str(tmp_path / "restart"), "--quiet")
    again = final_frame(tmp_path / "restart")
    for name in ("x", "v", "J", "model", "damage", "EE"):
        assert np.array_equal(again[name], frames[2][name]), f"restart: {name}"

"""SPB-MPM on 1 (in process), 2 and 4 (oversubscribed) ranks: the stretched bar (coarse, pulled fast so it
converts and tears within a few hundred steps) gives the same PD set and the same broken
bonds (damage bitwise), the same load-balance weights by id (the active half-bonds counted
from each rank's bond rows, bitwise), positions and velocities within 1e-10, and the
smallest relative distance of any G_i to G_EE and of any bond energy to its threshold is reported (round-off
between rank counts must stay below it). A fixed dt makes every rank count take the same
steps."""

from pathlib import Path

import numpy as np

from hpcmpm.pd.load import bond_cost
from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene
from scene_runs import hpcmpm, last_frame, run_scene

SCENE = "inputs/spb_stretched_bar_2d.toml"
DT, STEPS = 4e-5, 200
SETS = ["simulation.dx=0.014", f"simulation.dt={DT}", f"simulation.end_time={DT * STEPS}",
        f"output.every={DT * STEPS}", "materials.0.failure.grid_energy=3376.8",
        "materials.0.failure.bond_energy=0.5", "prescribed.0.velocity=[0.0, -3.0]",
        "prescribed.1.velocity=[0.0, 3.0]", 'output.fields=["active_bonds"]']


def final_frame(out: Path) -> dict:
    return last_frame(out, STEPS)


def run(ranks: int, out: Path, *extra) -> dict:
    return run_scene(ranks, SCENE, SETS, out, STEPS, *extra)


def test_spb_bar_matches_across_rank_counts(tmp_path):
    sim = simulate(load_scene(SCENE, SETS))
    ext = sim.extensions[0]
    margins = ext.margins(sim.domain)
    p = sim.particles
    order = np.argsort(p["id"])
    ref = {k: p[k][order] for k in ("id", "x", "v", "model", "damage", "active_bonds")}
    weights = sim.load_weights()[order]
    print(f"1 rank: PD {int((ref['model'] == 1).sum())} of {len(order)}, damaged "
          f"{int((ref['damage'] > 0).sum())}, smallest margins: G_i to G_EE "
          f"{margins['flag']:.2e}, bond energy to beta W_c {margins['bond']:.2e}")
    assert 0.05 * len(order) < (ref["model"] == 1).sum() < len(order)   # partly converted
    assert ref["damage"].max() > 0.3                                    # and torn
    # The weights are each particle's own: 1 unit, plus c_b x its intact half-bonds once PD
    # (surface and torn particles fewer than an interior family: the counts differ).
    pd = ref["model"] == 1
    unit = sim.particle_weight
    assert np.all(weights[~pd] == unit) and len(np.unique(ref["active_bonds"][pd])) > 3
    assert np.array_equal(weights[pd], unit + np.rint(
        unit * bond_cost(2, "correspondence") * ref["active_bonds"][pd]).astype(np.int64))
    frames = {}
    for ranks in (2, 4):                  # 1 rank: the in-process run above
        extra = ["--checkpoint-every", str(STEPS // 2)] if ranks == 2 else []
        got = frames[ranks] = run(ranks, tmp_path / f"n{ranks}", *extra)
        assert np.array_equal(got["id"], ref["id"])
        assert np.array_equal(got["model"], ref["model"]), f"{ranks} ranks: PD set"
        assert np.array_equal(got["damage"], ref["damage"]), f"{ranks} ranks: broken bonds"
        # The load-balance weight is a function of (model, active_bonds) alone.
        assert np.array_equal(got["active_bonds"], ref["active_bonds"]), f"{ranks} ranks: weights"
        for name in ("x", "v"):
            err = np.abs(got[name] - ref[name]).max() / np.abs(ref[name]).max()
            # Round-off from the grid's summation order, amplified over the steps.
            assert err < 1e-10, f"{ranks} ranks: {name} differs by {err:.2e}"

    # Restart on the same rank count from the checkpoint at half-way (PD particles, bonds,
    # broken ones and EE_p in it): bitwise the uninterrupted run.
    ckpt = tmp_path / "n2" / f"ckpt_{STEPS // 2:09d}.h5"
    assert ckpt.exists()
    hpcmpm(2, "restart", str(ckpt), "--out", str(tmp_path / "restart"), "--quiet")
    again = final_frame(tmp_path / "restart")
    for name in ("x", "v", "F", "model", "damage", "EE", "active_bonds"):
        assert np.array_equal(again[name], frames[2][name]), f"restart: {name}"


# The clamp (hpcmpm/pd/clamp.py) across ranks: the round-1 bar lying on a sticky floor and
# clamped at x = 0, every particle PD within the first steps (a tiny G_EE). The cuts of 2 and
# 4 ranks run across the floor, so ghost bonds take their sources' A and F from the halo.
CLAMP_SCENE = "inputs/bar_2d.toml"
CLAMP_DT, CLAMP_STEPS = 0.01, 200
CLAMP_SETS = [f"simulation.end_time={CLAMP_DT * CLAMP_STEPS}", f"simulation.dt={CLAMP_DT}",
              f"output.every={CLAMP_DT * CLAMP_STEPS}", "bodies.0.lower=[0.0, 0.0]",
              "bodies.0.upper=[25.0, 1.0]", 'walls.y_lower={condition="sticky"}',
              'materials.0.failure={model="spb", grid_energy=1e-12, bond_energy=inf}']


def test_spb_clamp_matches_across_rank_counts(tmp_path):
    sim = simulate(load_scene(CLAMP_SCENE, CLAMP_SETS))
    p = sim.particles
    order = np.argsort(p["id"])
    ref = {k: p[k][order] for k in ("id", "x", "v", "model")}
    assert (ref["model"] == 1).all()
    for ranks in (2, 4):
        data = run_scene(ranks, CLAMP_SCENE, CLAMP_SETS, tmp_path / f"n{ranks}", CLAMP_STEPS)
        assert np.array_equal(data["id"], ref["id"])
        assert np.array_equal(data["model"], ref["model"])
        for name in ("x", "v"):
            err = np.abs(data[name] - ref[name]).max() / np.abs(ref[name]).max()
            # Round-off from the grid's summation order, amplified over the steps.
            assert err < 1e-10, f"{ranks} ranks: {name} differs by {err:.2e}"

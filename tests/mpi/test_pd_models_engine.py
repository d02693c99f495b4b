"""The 003 ch. 5 models and the Kalthoff-Winkler scene through `mpiexec -n N hpcmpm run` on
1, 2 and 4 (oversubscribed) ranks, reduced in size, compared by id in the last frame (as
test_pd_engine.py): kalthoff_winkler_2d (PMB off the grid, a prescribed set moving PD
particles) bitwise equal with the same broken bonds; ibmpm_wall_fracture_2d (bond_energy with
bond plasticity, crack planes gathered over ranks, two-time integration, on the grid) within
1e-10 with the same broken bonds. And a restart of ibmpm_cream_pie_2d (viscoelastic_lps: the
per-bond stored forces checkpoint with the bonds; the pie clamped to its wall) bitwise equal
to the uninterrupted run."""

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.io.checkpoint import latest_checkpoint
from launch import mpi_hpcmpm
from scene_runs import last_frame

STEPS = 60
# scene: (fixed dt below the scene's stable step, bitwise, reductions)
SCENES = {
    "kalthoff_winkler_2d": (4e-7, True, ["simulation.dx=0.01",
                                         "prescribed.0.region.upper=[0.015, 0.025]"]),
    # The ball starts 1.5 mm from the wall: it strikes within the run, bonds break.
    "ibmpm_wall_fracture_2d": (6e-5, False, ["bodies.1.center=[0.4585, 0.3]",
                                             "bodies.1.velocity=[8.0, 0.0]"]),
}


def hpcmpm(ranks: int, *args):
    proc = mpi_hpcmpm(ranks, *args, "--quiet", timeout=600)
    assert "exceeds the CFL bound" not in proc.stderr
    return proc


def run(scene: str, ranks: int, out: Path, dt: float, sets) -> dict:
    end = STEPS * dt
    extra = [a for s in sets for a in ("--set", s)]
    hpcmpm(ranks, "run", f"inputs/{scene}.toml", "--out", str(out), "--force",
           "--set", f"simulation.dt={dt}", "--set", f"simulation.end_time={end}",
           "--set", f"output.every={end}", *extra)
    return last_frame(out, STEPS, ranks)


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_pd_model_scenes_match_across_rank_counts(tmp_path, scene):
    dt, bitwise, sets = SCENES[scene]
    ref = run(scene, 1, tmp_path / "n1", dt, sets)
    assert ref["damage"].max() > 0.1          # bonds broke: the comparison covers failure
    for ranks in (2, 4):
        got = run(scene, ranks, tmp_path / f"n{ranks}", dt, sets)
        assert np.array_equal(got["id"], ref["id"])
        for name in ("x", "v", "damage"):
            if bitwise:
                assert np.array_equal(got[name], ref[name]), f"{ranks} ranks: {name}"
            else:
                err = np.abs(got[name] - ref[name]).max() / np.abs(ref[name]).max()
                # Round-off of the grid's summation order over 60 steps.
                assert err < 1e-10, f"{ranks} ranks: {name} differs by {err:.2e}"
        assert np.array_equal(got["damage"] > 0, ref["damage"] > 0)


def set_own_ghost_state(path, name, value):
    """In the ghost-store checkpoint ``path`` (clamp.ghost_store), the state ``name`` of
    every particle's ghost bond to its own image (the entries at position 0) set to
    ``value``, the checksum made to match."""
    import h5py

    from hpcmpm.io import checksum as cks

    with h5py.File(path, "r+") as h:
        own = h["particles/partner"][:] == 0
        dset = h[f"particles/state.{name}"]
        data = dset[:]
        data[own] = value
        dset[...] = data
        dset.attrs["checksum"] = cks.format_checksum(cks.checksum(data))


def restart_reads_the_state(tmp_path, scene, sets, dt, alter, state_check):
    """2 ranks, 50 steps of ``scene`` with ``sets`` (the reference), and 25 steps with a
    checkpoint; ``state_check(checkpoint)`` looks at it; then the restart to step 50 must be
    bitwise the reference, and a restart from a copy of the checkpoint changed by
    ``alter(checkpoint copy)`` must not. Returns the reference frame."""
    import shutil

    fixed = ["--set", f"simulation.dt={dt}", "--set", f"output.every={25 * dt}", *sets]
    full = tmp_path / "full"
    hpcmpm(2, "run", scene, "--out", str(full), "--end-time", str(50 * dt), *fixed)
    ref = last_frame(full, 50, 2)
    part = tmp_path / "part"
    hpcmpm(2, "run", scene, "--out", str(part), "--end-time", str(25 * dt), *fixed)
    ckpt = latest_checkpoint(part)
    state_check(ckpt)
    altered = tmp_path / "altered"
    shutil.copytree(part, altered)
    alter(altered / ckpt.name)
    hpcmpm(2, "restart", str(ckpt), "--end-time", str(50 * dt))
    got = last_frame(part, 50, 2)
    assert np.array_equal(got["id"], ref["id"])
    for name in ("x", "v"):
        assert np.array_equal(got[name], ref[name]), name
    hpcmpm(2, "restart", str(altered / ckpt.name), "--end-time", str(50 * dt))
    assert not np.array_equal(last_frame(altered, 50, 2)["x"], ref["x"])
    return ref


def test_viscoelastic_bond_state_restarts_bitwise(tmp_path):
    """The pie thrown against its sticky wall from next to it, so the PD clamp holds it:
    the per-bond stored forces and lengths, and the clamp's ghost store (its own folder,
    entries only for the particles within reach of the wall), checkpoint; a 2-rank restart
    is bitwise the uninterrupted run (positions would differ if the stored forces or lengths
    had been lost), and one with the stored forces of the particles' own ghost bonds zeroed
    is not."""
    import h5py

    def ghosts(ckpt):
        return ckpt.parent / "pd_ghost_bonds_cream" / ckpt.name

    def check(ckpt):
        assert (ckpt.parent / "pd_bonds_cream" / ckpt.name).exists()
        with h5py.File(ghosts(ckpt)) as h:
            own = h["particles/partner"][:] == 0
            iso = h["particles/state.ve_mirror_iso0"][:]
            dev = h["particles/state.ve_mirror_dev0"][:]
            owners = h["particles/owner"][:]
        with h5py.File(ckpt) as h:
            n = len(h["particles/id"])
        # The clamp acts, and only the particles within reach have entries.
        assert np.count_nonzero(iso[own]) > 5 and np.count_nonzero(dev) > 10
        assert 0 < len(np.unique(owners)) < n / 2

    restart_reads_the_state(tmp_path, "inputs/ibmpm_cream_pie_2d.toml",
                            ["--set", "bodies.0.center=[1.84, 0.6]"], 2e-3,
                            lambda c: set_own_ghost_state(ghosts(c), "ve_mirror_iso0", 0.0),
                            check)


def test_clamped_bond_plasticity_restarts_bitwise(tmp_path):
    """ibmpm_wall_fracture_2d with its wall made a low slab sliding on the sticky floor (an
    initial sideways velocity): the clamp's ghost bonds at the floor yield (bond_energy.py,
    `bond_energy_clamp_terms`), and their plastic stretches (a bond state per face and a
    ghost-store entry for each particle's own image) checkpoint with the run: a 2-rank restart
    from the half-way checkpoint is bitwise the uninterrupted run, and the same restart with
    the particles' ghost stretches changed in the checkpoint is not (the restart reads them).
    The run on 1 rank agrees with the 2-rank run to 1e-10.
    Zeroing them would not show it: the scene is perfectly plastic, and a bond that keeps
    flowing returns to the yield surface at e_p = e_dev -+ sqrt(2 psi_p) |X|/k whatever its
    old e_p (the corrected eq. 5.11), so a flowing bond's history is erased every step."""
    import h5py

    dt = 6e-5
    # The wall made a low slab across the floor, so the ranks' cut (along x) runs through
    # the clamped rows: ghost bonds whose source is a halo point yield.
    sets = ["--set", "bodies.0.velocity=[2.0, 0.0]", "--set", "bodies.0.lower=[0.1, 0.0]",
            "--set", "bodies.0.upper=[0.9, 0.06]"]
    scene = "inputs/ibmpm_wall_fracture_2d.toml"

    def ghosts(ckpt):
        return ckpt.parent / "pd_ghost_bonds_wall" / ckpt.name

    def check(ckpt):
        with h5py.File(ghosts(ckpt)) as h:
            own = h["particles/partner"][:] == 0
            mirror = h["particles/state.mirror_plastic_stretch0"][:]
        # They yielded: own images and partners' images.
        assert np.count_nonzero(mirror[own]) > 10 and np.count_nonzero(mirror[~own]) > 100

    # 0.5: a plastic stretch beyond every bond's current stretch.
    ref = restart_reads_the_state(
        tmp_path, scene, sets, dt,
        lambda c: set_own_ghost_state(ghosts(c), "mirror_plastic_stretch0", 0.5), check)
    # One rank: on two the ghost bonds by the cut read their sources' image mean stretch
    # from the halo.
    one = tmp_path / "one"
    hpcmpm(1, "run", scene, "--out", str(one), "--end-time", str(50 * dt),
           "--set", f"simulation.dt={dt}", "--set", f"output.every={25 * dt}", *sets)
    single = last_frame(one, 50, 1)
    for name in ("x", "v"):
        err = np.abs(single[name] - ref[name]).max() / np.abs(ref[name]).max()
        assert err < 1e-10, f"1 against 2 ranks: {name} differs by {err:.2e}"  # grid round-off

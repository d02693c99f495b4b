"""Peridynamic bonds across a periodic axis: a strip that spans the period translates at
constant velocity through several wraps with no internal force (its bonds wrap with it), and
1, 2 and 4 ranks agree bitwise.

A strip sheared along the axis (upper half to -x, lower half to +x, far below the critical
stretch) moves its particles in both directions: no bond breaks, 1 and 2 ranks agree.

A strip 2 cells high, periodic along y too, checks that a family holding two images of one
partner keeps each (bonds.image_label) on 1 and 2 ranks and through a restart."""

import h5py
import numpy as np

from hpcmpm.io.checkpoint import latest_checkpoint
from launch import mpi_hpcmpm
from scene_runs import last_frame

SCENE = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [0.4, 0.4] }
periodic = ["x"]
dx = 0.02
particles_per_cell = 2
kernel = "quadratic"
transfer = "mls"
cfl = 0.4
end_time = 3.2e-4
dt = 1.6e-6

[output]
every = 3.2e-4

[[materials]]
name = "glass"
type = "peridynamic"
model = "lps"
integration = "pd"
density = 2500.0
E = 7.2e10
nu = 0.25
critical_stretch = 0.01

[[bodies]]
name = "strip"
material = "glass"
shape = "box"
lower = [0.0, 0.1]
upper = [0.4, 0.3]
velocity = [150.0, 0.0]
"""


def test_pd_strip_across_a_periodic_axis(tmp_path):
    """260 steps at 625 m/s carry the strip 0.26 m, past half the period 0.4 at step 200.
    Before reference positions moved with the wraps (`Domain.wrap_particles`), they followed
    by a rule, x0 shifted by round((x - x0) / P) periods, which split the particles by
    round-off where the displacement reached half a period: 26712 half-bonds broke and
    velocities reached 1.5e5 m/s (measured, in process)."""
    scene = tmp_path / "strip.toml"
    scene.write_text(SCENE.replace("velocity = [150.0, 0.0]", "velocity = [625.0, 0.0]")
                     .replace("end_time = 3.2e-4", "end_time = 4.16e-4")
                     .replace("every = 3.2e-4", "every = 4.16e-4"))
    frames = {}
    for ranks in (1, 2, 4):
        out = tmp_path / f"n{ranks}"
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force")
        frames[ranks] = last_frame(out, 260, ranks)
    ref = frames[1]
    # Its wrapped particles keep their bonds, or the broken families would pull (a bond
    # missing across the face unbalances its end). 1e-8 of the velocity: forces are
    # round-off of positions ~1e-16 m over bonds ~1e-2 m (measured 4e-13).
    assert np.abs(ref["v"][:, 0] - 625.0).max() < 1e-8 * 625.0
    assert np.abs(ref["v"][:, 1]).max() < 1e-8 * 625.0
    for ranks in (2, 4):
        for name in ("id", "x", "v"):
            assert np.array_equal(frames[ranks][name], ref[name]), f"{ranks} ranks: {name}"

# The same strip split in two halves sliding against each other, 50 steps.
SHEAR = (SCENE.split("[[bodies]]")[0]
         .replace("end_time = 3.2e-4", "end_time = 8e-5")
         .replace("every = 3.2e-4", 'every = 8e-5\nfields = ["damage"]')
         .replace("critical_stretch = 0.01", "critical_stretch = 0.05") + """
[[bodies]]
name = "lower"
material = "glass"
shape = "box"
lower = [0.0, 0.1]
upper = [0.4, 0.2]
velocity = [0.5, 0.0]

[[bodies]]
name = "upper"
material = "glass"
shape = "box"
lower = [0.0, 0.2]
upper = [0.4, 0.3]
velocity = [-0.5, 0.0]
""")


def test_pd_strip_sheared_along_a_periodic_axis(tmp_path):
    scene = tmp_path / "shear.toml"
    scene.write_text(SHEAR)
    frames = {}
    for ranks in (1, 2):
        out = tmp_path / f"n{ranks}"
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force")
        frames[ranks] = last_frame(out, 50, ranks)
    ref = frames[1]
    # 50 steps: the halves slipped 8e-5 m against each other, a bond stretch of at most
    # ~4e-3 at 0.01 m spacing, so none breaks (measured: damage 0).
    assert ref["damage"].max() == 0.0
    assert (ref["v"][:, 0] > 0).any() and (ref["v"][:, 0] < 0).any()
    for name in ("id", "x", "v", "damage"):
        assert np.array_equal(frames[2][name], ref[name]), f"2 ranks: {name}"


def test_pd_crack_drawn_from_a_periodic_face_cuts_both_ends_of_its_bonds(tmp_path):
    """The sheared strip with a pre-crack from the face x = 0 into the strip (y = 0.15,
    between two particle rows: the diagonal bonds across the face pass through its end, a
    tie). Each half-bond across the face is tested from its own end, once against the crack
    and once against its image one period away; both must agree, or a bond pulls one end
    and not the other. Momentum starts at exactly 0 (equal masses at +-0.5 m/s); before the
    crack's images and the shared bond segment (families._bond_segment) it reached 4e-3 of
    sum |m v| in 50 steps (measured, 6 one-sided half-bonds), now 9e-12 (the periodic
    images' round-off). 1 and 2 ranks bitwise."""
    scene = tmp_path / "cracked.toml"
    scene.write_text(SHEAR.replace("critical_stretch = 0.05", "critical_stretch = 0.05\n"
                                   "precracks = [[[0.0, 0.15], [0.1, 0.15]]]"))
    frames = {}
    for ranks in (1, 2):
        out = tmp_path / f"n{ranks}"
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force")
        frames[ranks] = last_frame(out, 50, ranks)
    v = frames[1]["v"]
    # Equal masses: the momentum is m sum v. 1e-9 of sum |v|: the stiff glass's round-off
    # from image positions (1.3e-10 over 500 steps of the uncracked strip, measured).
    assert np.abs(v.sum(axis=0)).max() < 1e-9 * np.abs(v).sum()
    for name in ("id", "x", "v", "damage"):
        assert np.array_equal(frames[2][name], frames[1][name]), f"2 ranks: {name}"


# A strip 2 cells high, periodic along y too (period 0.04: the LPS family radius 0.035 lies
# between half the period and the period, so a family holds both images of some partners:
# 3520 of the 5760 half-bonds), its left half sliding up and its right half down: a motion that
# does not vary along y.
NARROW = (SCENE.split("[[bodies]]")[0]
          .replace("upper = [0.4, 0.4] }", "upper = [0.4, 0.04] }")
          .replace('periodic = ["x"]', 'periodic = ["x", "y"]')
          .replace("end_time = 3.2e-4", "end_time = 8e-5")
          .replace("every = 3.2e-4", 'every = 4e-5\nfields = ["damage"]')
          .replace("critical_stretch = 0.01", "critical_stretch = 0.05") + """
[[bodies]]
name = "left"
material = "glass"
shape = "box"
lower = [0.0, 0.0]
upper = [0.2, 0.04]
velocity = [0.0, 0.5]

[[bodies]]
name = "right"
material = "glass"
shape = "box"
lower = [0.2, 0.0]
upper = [0.4, 0.04]
velocity = [0.0, -0.5]
""")


def test_pd_families_hold_both_images_across_a_narrow_periodic_axis(tmp_path):
    """Each column of the narrow strip moves as one (the lattice is infinite along y), on 1
    and 2 ranks bitwise alike and through a restart at step 25: every half-bond keeps its
    image of its partner (bonds.image_label) through halo rebuilds, migration and the
    checkpoint. Before the labels, both half-bonds to such a partner took its nearest copy
    at the first halo rebuild: the spread of v within a column was 0.71 m/s at step 50, 1.4
    times the speed (measured); with the labels 8.2e-11."""
    scene = tmp_path / "narrow.toml"
    scene.write_text(NARROW)
    frames = {}
    for ranks in (1, 2):
        out = tmp_path / f"n{ranks}"
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force")
        frames[ranks] = last_frame(out, 50, ranks)
    part = tmp_path / "part"
    mpi_hpcmpm(2, "run", str(scene), "--out", str(part), "--quiet", "--force",
               "--end-time", "4e-5")
    mpi_hpcmpm(1, "restart", str(latest_checkpoint(part)), "--end-time", "8e-5", "--quiet")
    frames["restart"] = last_frame(part, 50, 1)
    ref = frames[1]
    column = np.floor(np.mod(ref["x"][:, 0], 0.4) / 0.01 + 1e-6).astype(int)
    spread = max(np.ptp(ref["v"][column == c], axis=0).max() for c in np.unique(column))
    print(f"largest spread of v within a column: {spread:.3g}")
    # Columns: particles started on one x and move only along y (x-forces cancel by the
    # lattice's symmetry), so x still tells the column. 1e-8 of the speed: round-off of
    # stiff forces (E = 7.2e10) from positions ~1e-16 m over bonds ~1e-2 m, 50 steps
    # (measured 1.6e-10 of it).
    assert spread < 1e-8 * 0.5
    assert ref["damage"].max() == 0.0
    assert np.abs(ref["v"][:, 1]).max() > 0.4        # the halves still slide
    for key in (2, "restart"):
        for name in ("id", "x", "v", "damage"):
            assert np.array_equal(frames[key][name], ref[name]), f"{key}: {name}"


# SPB-MPM: a block straddling the periodic face x = 0 (two bodies), sliding along x as it
# falls onto the floor, converts to PD at impact and tears; its families reach across the
# face (pd/spb.py, the conversions' search over images).
SPB_DROP = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
periodic = ["x"]
dx = 0.05
transfer = "mls"
end_time = 0.012
dt = 1e-4
gravity = [0.0, -9.81]

[output]
every = 0.006

[[materials]]
name = "m"
type = "linear_elastic"
density = 1000.0
E = 1.0e4
nu = 0.3
failure = { model = "spb", grid_energy = 0.01, bond_energy = 0.5 }

[[bodies]]
material = "m"
shape = "box"
lower = [0.85, 0.1]
upper = [1.0, 0.3]
velocity = [3.0, -5.0]

[[bodies]]
material = "m"
shape = "box"
lower = [0.0, 0.1]
upper = [0.15, 0.3]
velocity = [3.0, -5.0]
"""


def test_spb_block_across_a_periodic_face_matches_across_rank_counts(tmp_path):
    """1 and 2 ranks: the same PD set and broken bonds (bitwise), positions and velocities
    to round-off, while the converted block crosses the face x = 0. A restart on 2 ranks
    from the checkpoint at step 100 (the block converted at steps 81-90: PD particles whose
    reference positions followed them across the face, bonds that cross it) is bitwise the
    uninterrupted run."""
    scene = tmp_path / "drop.toml"
    scene.write_text(SPB_DROP)
    frames = {}
    for ranks in (1, 2):
        out = tmp_path / f"n{ranks}"
        extra = ["--checkpoint-every", "100"] if ranks == 2 else []
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force", *extra)
        frames[ranks] = last_frame(out, 120, ranks)
    ckpt = tmp_path / "n2" / f"ckpt_{100:09d}.h5"
    mpi_hpcmpm(2, "restart", str(ckpt), "--out", str(tmp_path / "restart"), "--quiet")
    again = last_frame(tmp_path / "restart", 120, 2)
    with h5py.File(ckpt, "r") as f:
        converted = int((f["particles/model"][...] == 1).sum())
    assert converted == len(again["id"])      # the checkpoint holds the converted block
    assert {"x", "v", "F", "model", "damage", "EE"} <= again.keys()
    for name in again:
        assert np.array_equal(again[name], frames[2][name]), f"restart: {name}"
    ref, got = frames[1], frames[2]
    print(f"PD {int((ref['model'] == 1).sum())} of {len(ref['id'])}, damaged "
          f"{int((ref['damage'] > 0).sum())}")
    assert (ref["model"] == 1).sum() > len(ref["id"]) // 2 and ref["damage"].max() > 0
    assert np.array_equal(got["id"], ref["id"])
    assert np.array_equal(got["model"], ref["model"])
    assert np.array_equal(got["damage"], ref["damage"])
    # Sums over bonds and nodes taken in another order on 2 ranks: round-off, 1e-10 as the
    # SPB bar's rank test (tests/mpi/test_spb_ranks.py).
    for name in ("x", "v"):
        assert np.abs(got[name] - ref[name]).max() < 1e-10 * max(1.0, np.abs(ref[name]).max())

"""Peridynamic bonds across a periodic axis: a strip that spans the period translates at
constant velocity through several wraps with no internal force (its bonds wrap with it), and
1, 2 and 4 ranks agree bitwise.

A strip sheared along the axis (upper half to -x, lower half to +x, far below the critical
stretch) checks the other direction: each particle's reference position follows its own
wraps only (`PDExtension._follow_periodic_wrap`: x - x0 kept within half a period), so no
bond breaks. Moving every particle the same way, a wrong rounding of the turns shifts all
x0 alike and goes unnoticed."""

import numpy as np

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
    scene = tmp_path / "strip.toml"
    scene.write_text(SCENE)
    frames = {}
    for ranks in (1, 2, 4):
        out = tmp_path / f"n{ranks}"
        mpi_hpcmpm(ranks, "run", str(scene), "--out", str(out), "--quiet", "--force")
        frames[ranks] = last_frame(out, 200, ranks)
    ref = frames[1]
    # 200 steps at 150 m/s carry the strip 0.048 m: its wrapped particles keep their bonds, or
    # the broken families would pull (a bond missing across the face unbalances its end).
    # 1e-8 of the velocity: forces are round-off of positions ~1e-16 m over bonds ~1e-2 m.
    assert np.abs(ref["v"][:, 0] - 150.0).max() < 1e-8 * 150.0
    assert np.abs(ref["v"][:, 1]).max() < 1e-8 * 150.0
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
    # ~4e-3 at 0.01 m spacing, so none breaks (measured: damage 0). Rounding the turns down
    # instead (np.floor) moves the reference position of every particle going to -x back by
    # a period at its first step: measured damage 1.0.
    assert ref["damage"].max() == 0.0
    assert (ref["v"][:, 0] > 0).any() and (ref["v"][:, 0] < 0).any()
    for name in ("id", "x", "v", "damage"):
        assert np.array_equal(frames[2][name], ref[name]), f"2 ranks: {name}"

"""SPB-MPM on a periodic axis (hpcmpm/pd/spb.py, Domain.wrap_particles): a converted body
keeps its bonds while it crosses a face, and a body converted across a face gets the families
it would get away from one.

Before the reference positions of SPB particles followed their periodic wraps, and before
the conversions' bond search saw images across the faces, a block of 96 particles (all PD
from the first step, no bond failure possible under rigid motion) translating through the
face at x = 1 broke 2044 half-bonds as its particles wrapped (a wrapped particle's bonds
measured a period of stretch), and a block straddling the face converted with 2120
half-bonds against the 2476 of the same block inside the box (measured)."""

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.errors import SceneError
from hpcmpm.parallel import Communicator
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

SCENE = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, {height}] }}
dx = 0.05
transfer = "mls"
end_time = 0.1
periodic = ["x"]
[[materials]]
name = "m"
type = "linear_elastic"
density = 1000.0
E = 1.0e4
nu = 0.3
failure = {{ model = "spb", grid_energy = 1.0, bond_energy = 0.5 }}
[[bodies]]
material = "m"
shape = "box"
lower = [{x0}, 0.1]
upper = [{x1}, 0.3]
velocity = [5.0, 0.0]
"""


def converted_block(x0: float, x1: float):
    """The block [x0, x1] x [0.1, 0.3] (x0 < 0: two bodies, the part beyond the face x = 0
    wrapped to x = 1), every particle PD from the first step (the patch test's "G_EE = 0",
    which a scene cannot ask for), moving at 5 m/s along x."""
    text = SCENE.format(x0=max(x0, 0.0), x1=x1, height=0.5)
    if x0 < 0:
        body = text[text.index("[[bodies]]"):]
        text += body.replace("lower = [0.0, 0.1]", f"lower = [{1.0 + x0}, 0.1]").replace(
            f"upper = [{x1}, 0.3]", "upper = [1.0, 0.3]")
    scene = parse_scene(text, "block.toml")
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    sim.extensions[0].convert_all = True
    return sim


def run(sim, end, observe=None):
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=end, quiet=True),
           observer=observe).run()


def test_converted_block_keeps_its_bonds_through_a_periodic_face():
    """The block moves rigidly from x in [0.6, 0.9] to [1.1, 1.4], through the face: every
    bond keeps its length, so none breaks and no force arises (round-off only)."""
    sim = converted_block(0.6, 0.9)
    worst = []
    run(sim, 0.1, lambda s: worst.append(np.abs(s.particles["v"] - [5.0, 0.0]).max()))
    ext = sim.extensions[0]
    p = sim.particles
    assert ext.pd_global == p.n and ext.bonds.n_bonds > 0
    assert (p["x"][:, 0] < 0.5).any()                  # some particles wrapped
    assert ext.broken == 0
    # 1e-12 of the speed: forces are round-off of positions over bonds of 2.5e-2.
    assert max(worst) < 1e-12 * 5.0


CORNER = """
[simulation]
dim = 3
domain = { lower = [0.0, 0.0, 0.0], upper = [1.0, 0.5, 0.5] }
dx = 0.05
transfer = "mls"
end_time = 0.1
periodic = ["x", "z"]
[[materials]]
name = "m"
type = "linear_elastic"
density = 1000.0
E = 1.0e4
nu = 0.3
failure = { model = "spb", grid_energy = 1.0, bond_energy = 0.5 }
"""
CORNER_BODY = """
[[bodies]]
material = "m"
shape = "box"
lower = [%s, 0.1, %s]
upper = [%s, 0.25, %s]
velocity = [5.0, 0.0, 2.0]
"""


def test_block_across_a_corner_keeps_its_bonds_past_half_a_period():
    """3D, periodic along x and z: a block straddling both faces (four boxes around the
    corner) converts with the families of the same block inside the box (26080 half-bonds)
    and moves rigidly at (5, 0, 2) m/s to t = 0.1, a displacement of exactly half the period
    along x: no bond breaks. With reference positions following their particles by the rule
    x0 += round((x - x0) / P) P, round-off split the particles at that step: 8638 half-bonds
    broke and velocities changed by 0.19 m/s (measured)."""
    def converted(boxes):
        text = CORNER + "".join(CORNER_BODY % (a, c, b, d) for a, b, c, d in boxes)
        scene = parse_scene(text, "corner.toml")
        sim = Simulation(scene, make_domain(scene, Communicator()))
        initial_particles(sim)
        sim.extensions[0].convert_all = True
        return sim

    inside = converted([(0.3, 0.5, 0.2, 0.35)])
    run(inside, 1e-3)
    sim = converted([(0.9, 1.0, 0.45, 0.5), (0.0, 0.1, 0.45, 0.5), (0.9, 1.0, 0.0, 0.1),
                     (0.0, 0.1, 0.0, 0.1)])
    worst = []
    run(sim, 0.1, lambda s: worst.append(np.abs(s.particles["v"] - [5.0, 0.0, 2.0]).max()))
    ext = sim.extensions[0]
    assert ext.pd_global == sim.particles.n == inside.particles.n
    assert ext.bonds.n_bonds == inside.extensions[0].bonds.n_bonds and ext.broken == 0
    assert max(worst) < 1e-12 * 5.0


def test_block_converted_across_a_periodic_face_gets_full_families():
    """The same block straddling the face (x in [0.85, 1.15], as two bodies [0.85, 1] and
    [0, 0.15]) converts with as many half-bonds as inside the box, of the same lengths: its
    families reach across."""
    counts = {}
    for where, (x0, x1) in {"inside": (0.35, 0.65), "across": (-0.15, 0.15)}.items():
        sim = converted_block(x0, x1)
        run(sim, 1e-3)
        ext = sim.extensions[0]
        assert ext.pd_global == sim.particles.n
        b = ext.bonds
        owner = np.repeat(np.arange(b.n), b.counts())
        length = np.linalg.norm(ext.pts_x0[b.slot] - ext.pts_x0[owner], axis=1)
        counts[where] = (b.n_bonds, np.sort(np.round(length / 0.0125).astype(int)))
    assert counts["across"][0] == counts["inside"][0]
    assert np.array_equal(counts["across"][1], counts["inside"][1])


def test_spb_horizon_reaching_half_a_period_is_a_scene_error():
    """A converted family would hold two images of one partner, which SPB's conversions do
    not build (a peridynamic material's families do): one line naming the key."""
    with pytest.raises(SceneError) as err:
        parse_scene(SCENE.format(x0=0.6, x1=0.9, height=0.5).replace(
            'upper = [1.0, 0.5] }', 'upper = [0.15, 0.5] }').replace(
            "lower = [0.6, 0.1]", "lower = [0.0, 0.1]").replace(
            "upper = [0.9, 0.3]", "upper = [0.15, 0.3]"), "narrow.toml")
    lines = str(err.value).splitlines()
    assert len(lines) == 1
    assert "materials[0].failure.horizon: the family radius 0.087875 reaches half the period " \
           "0.15 of the periodic axis x" in lines[0]


def test_spb_horizon_beyond_the_limit_is_one_line():
    """A horizon of 1e9 spacings: one line at the key, and no lattice of its size built
    (the SPB time step summed (2m + 2)^d points with numpy: out of memory)."""
    with pytest.raises(SceneError) as err:
        parse_scene(SCENE.format(x0=0.6, x1=0.9, height=0.5).replace(
            "model = \"spb\"", "model = \"spb\", horizon = 1e9"), "wide.toml")
    lines = str(err.value).splitlines()
    assert lines == ["wide.toml: materials[0].failure.horizon: 1e+09 particle spacings is more "
                     "than 256: a complete family would hold about 3.1e+18 half-bonds per "
                     "particle"]

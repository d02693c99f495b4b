"""Prescribed rigid motion of off-grid PD particles (hpcmpm/pd/boundary.py) and the domain
walls acting on them per particle (hpcmpm/pd/contact.py), against formulas written out here:
v = V + omega x (x - c(t)) on each set's own particles only, and the walls' projection on
every face of the box, periodic axes excluded."""

import types

import numpy as np
import pytest

from hpcmpm.boundaries.prescribed import PrescribedSet
from hpcmpm.pd.boundary import OffGridBoundaries, impose_prescribed_velocity
from hpcmpm.pd.contact import ParticleWalls


def prescribed(index, dim, velocity, omega, centre):
    spec = types.SimpleNamespace(region={"lower": [0.0] * dim, "upper": [1.0] * dim},
                                 velocity=velocity, angular_velocity=omega, center=centre)
    return PrescribedSet(spec, index, dim)


@pytest.mark.parametrize("dim", [2, 3])
def test_prescribed_sets_move_their_own_particles_rigidly_about_their_centre(dim):
    rng = np.random.default_rng(5 + dim)
    t = 0.7
    sets = [prescribed(0, dim, [0.1, -0.2, 0.3][:dim], 2.0 if dim == 2 else [0.5, -1.0, 2.0],
                       [0.4] * dim),
            prescribed(1, dim, [-0.3, 0.5, 0.2][:dim], -1.5 if dim == 2 else [1.0, 0.3, -0.7],
                       [0.6] * dim)]
    n, start, stop = 40, 5, 35
    tags = np.tile(np.array([-1, 0, 1, 1, 0], np.int32), n // 5)
    x = rng.uniform(0.0, 1.0, (n, dim))
    sim = types.SimpleNamespace(prescribed=sets, particles={"prescribed": tags, "x": x},
                                dim=dim, time=t)
    v0 = rng.normal(size=(stop - start, dim))
    v = v0.copy()
    impose_prescribed_velocity(sim, slice(start, stop), x[start:stop], v)
    rows = np.arange(start, stop)
    for k, s in enumerate(sets):
        mine = tags[rows] == k
        c = np.asarray(s.spec.center) + np.asarray(s.spec.velocity) * t    # c(t)
        r = x[rows[mine]] - c
        V = np.asarray(s.spec.velocity)
        if dim == 2:
            w = s.spec.angular_velocity
            want = V + w * np.stack([-r[:, 1], r[:, 0]], axis=1)
        else:
            w = np.asarray(s.spec.angular_velocity)
            want = V + np.stack([w[1] * r[:, 2] - w[2] * r[:, 1],
                                 w[2] * r[:, 0] - w[0] * r[:, 2],
                                 w[0] * r[:, 1] - w[1] * r[:, 0]], axis=1)
        assert mine.sum() >= 6
        # Round-off of a cross product of O(1) values (measured 0: the same operations).
        np.testing.assert_allclose(v[mine], want, rtol=0, atol=1e-14)
    free = tags[rows] < 0
    assert free.sum() > 0 and np.array_equal(v[free], v0[free])


WALLS = """
[simulation]
dim = {dim}
domain = {{ lower = [{lo}], upper = [{hi}] }}
dx = 0.1
end_time = 0.1
{periodic}
[[materials]]
name = "m"
type = "fixed_corotated"
density = 1.0
E = 1.0
nu = 0.3
[[bodies]]
material = "m"
shape = "box"
lower = [{blo}]
upper = [{bhi}]
[walls]
default = "{condition}"
friction = {friction}
"""


def walls(dim, periodic="", condition="slip", friction=0.0):
    from hpcmpm.scene import parse_scene

    text = WALLS.format(dim=dim, lo=", ".join(["0.0"] * dim), hi=", ".join(["1.0"] * dim),
                        blo=", ".join(["0.4"] * dim), bhi=", ".join(["0.6"] * dim),
                        periodic=periodic, condition=condition, friction=friction)
    return ParticleWalls(parse_scene(text, path="walls.toml"))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("condition", ["slip", "separate"])
def test_walls_project_the_velocity_into_every_face(dim, condition):
    """A particle about to cross face (axis a, side s) loses v_a; its tangential velocity
    stays (slip) or is shortened by Coulomb friction, |v_t'| = |v_t| - mu |v_a| (separate,
    mu = 0.25; the normal of each face points into the box, so the crossing velocity is
    approaching, not separating); a particle moving away from a face it is near keeps its
    velocity."""
    mu = 0.25 if condition == "separate" else 0.0
    dt = 0.01
    cases = []
    for axis in range(dim):
        for upper in (False, True):
            x = np.full(dim, 0.5)
            x[axis] = 0.995 if upper else 0.005
            v = np.arange(1.0, dim + 1.0)
            v[axis] = 2.0 if upper else -2.0        # crosses within dt (0.02 > 0.005)
            cases.append((x, v, axis))
            v_away = v.copy()
            v_away[axis] = -v[axis]                 # moving away: untouched
            cases.append((x, v_away, None))
    x = np.array([c[0] for c in cases])
    v = np.array([c[1] for c in cases])
    want = v.copy()
    for k, (_, _, axis) in enumerate(cases):
        if axis is not None:
            want[k, axis] = 0.0
            vt = np.linalg.norm(want[k])
            want[k] *= 1.0 - mu * abs(v[k, axis]) / vt
    got = v.copy()
    hits = walls(dim, condition=condition, friction=mu).apply(x, got, dt)
    assert hits == 2 * dim
    # Round-off of the friction scale (measured 0 here, slip and separate alike).
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)


def test_periodic_axes_have_no_walls():
    dt = 0.01
    x = np.array([[0.005, 0.5], [0.5, 0.005], [0.995, 0.5]])
    v = np.array([[-2.0, 1.0], [1.0, -2.0], [2.0, 1.0]])
    got = v.copy()
    hits = walls(2, 'periodic = ["x"]').apply(x, got, dt)
    assert hits == 1
    assert np.array_equal(got, [[-2.0, 1.0], [1.0, 0.0], [2.0, 1.0]])


def test_off_grid_step_prescribed_velocity_wins_over_the_walls():
    """`PDBodyExtension.after_g2p` (003 Alg. 2 off the grid): v += dt (f/m + g), then the
    walls, the colliders, and last the prescribed sets' rigid velocity, which wins: an
    impactor driven into the floor keeps its prescribed velocity, a free particle next to it
    loses its normal velocity (slip); x += dt v. The force pass is stubbed."""
    import contextlib

    from hpcmpm.pd.extension import PDBodyExtension

    dt, t = 0.01, 0.0
    s = prescribed(0, 2, [0.5, -3.0], None, [0.5, 0.5])
    x = np.array([[0.3, 0.01], [0.6, 0.01], [0.5, 0.5]])
    v = np.array([[0.5, -3.0], [0.5, -3.0], [1.0, 1.0]])
    f = np.array([[0.0, 0.0], [0.0, 0.0], [2.0, -4.0]])
    mass = np.array([1.0, 1.0, 2.0])
    p = {"x": x.copy(), "v": v.copy(), "mass": mass, "prescribed": np.array([-1, 0, -1])}
    g = np.array([0.0, -10.0, 0.0])
    sim = types.SimpleNamespace(particles=p, gravity=g, dim=2, time=t, prescribed=[s],
                                phase=lambda name: contextlib.nullcontext())
    ext = object.__new__(PDBodyExtension)
    ext.prepare = lambda: (0, 3)
    ext.compute_forces = lambda start, stop: f
    ext.write_damage = lambda start, stop: None
    ext.model = types.SimpleNamespace()
    ext.boundaries = object.__new__(OffGridBoundaries)
    ext.boundaries.walls = walls(2)
    ext.boundaries.colliders = types.SimpleNamespace(apply=lambda x, v, t, dt: 0)
    ext.after_g2p(sim, dt)
    free = v + dt * (f / mass[:, None] + g[:2])
    want = np.array([[free[0, 0], 0.0], [0.5, -3.0], free[2]])
    assert np.array_equal(p["v"], want)
    assert np.array_equal(p["x"], x + dt * want)

"""Walls, colliders and prescribed sets against the analytic projections."""

import types

import numpy as np
import pytest

from hpcmpm.boundaries.colliders import Collider
from hpcmpm.boundaries.contact import SEPARATE, SLIP, STICKY, project
from hpcmpm.boundaries.prescribed import PrescribedSet, scatter_marks
from hpcmpm.boundaries.walls import Walls
from hpcmpm.kernels.shape import evaluate


def face(condition, friction=0.0):
    return types.SimpleNamespace(condition=condition, friction=friction)


def test_projection_formulas():
    # Moving into the obstacle (normal +y) with v = (3, -1, 0).
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, STICKY, 0.0) == (0.0, 0.0, 0.0)
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SLIP, 0.5) == (3.0, 0.0, 0.0)
    # Coulomb: tangential speed 3 loses friction * |v_n| = 0.5 * 1.
    assert np.allclose(project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 0.5), (2.5, 0, 0),
                       atol=1e-15)
    # Friction large enough to stop it: never reversed.
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 5.0) == (0.0, 0.0, 0.0)
    # Separating: untouched.
    assert project(3.0, 1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 0.5) == (3.0, 1.0, 0.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_walls_act_only_on_nodes_on_or_beyond_each_face(dim):
    n_cells = np.full(dim, 10)
    origin = np.full(dim, -2)
    shape = (15,) * dim
    rng = np.random.default_rng(0)
    v = rng.normal(size=shape + (dim,))
    mass = np.ones(shape)
    walls = Walls([face("slip")] * (2 * dim), n_cells)
    out = v.copy()
    walls.apply(out, origin, 0.1, np.zeros(dim), 0.0, 0.01, mass)
    idx = np.indices(shape) + origin.reshape((dim,) + (1,) * dim)
    for a in range(dim):
        beyond = (idx[a] <= 0) | (idx[a] >= 10)
        assert np.all(out[..., a][beyond] == 0.0)
        inside = np.all([(idx[b] > 0) & (idx[b] < 10) for b in range(dim)], axis=0)
        assert np.array_equal(out[inside], v[inside])


def test_separating_floor_with_friction_decelerates_at_mu_g():
    """A node sliding on a separating floor under gravity: v_t(t) = v0 - mu g t until it
    stops (Coulomb friction), applied the way the grid update does it each step."""
    mu, g, v0, dt = 0.3, 9.81, 2.0, 1e-3
    walls = Walls([face("slip"), face("slip"), face("separate", mu), face("slip")],
                  np.array([10, 10]))
    v = np.zeros((1, 1, 2))
    v[0, 0, 0] = v0
    mass = np.ones((1, 1))
    history = []
    for _ in range(1000):
        v[0, 0, 1] -= g * dt  # gravity pushes into the floor
        walls.apply(v, np.array([5, 0]), 0.1, np.zeros(2), 0.0, dt, mass)
        history.append(v[0, 0, 0])
    t = dt * np.arange(1, 1001)
    expected = np.maximum(v0 - mu * g * t, 0.0)
    assert np.allclose(history, expected, atol=1e-12)
    assert v[0, 0, 1] == 0.0


def collider(shape, params, condition="sticky", velocity=None, omega=None, friction=0.0):
    return types.SimpleNamespace(name="c", shape=shape, params=params, condition=condition,
                                 friction=friction, velocity=velocity, angular_velocity=omega,
                                 start=0.0, end=np.inf)


def test_kinematic_sphere_imposes_rigid_velocity_inside_only():
    dx = 0.1
    shape = (21, 21, 21)
    origin = np.zeros(3, dtype=np.int64)
    omega = np.array([0.0, 1.0, 2.0])
    c = Collider(collider("sphere", {"center": [1.0, 1.0, 1.0], "radius": 0.5},
                          velocity=[0.2, 0.0, 0.0], omega=omega), 3)
    v = np.zeros(shape + (3,))
    c.apply(v, origin, dx, np.zeros(3), 0.0, 0.5, np.ones(shape))
    x = np.stack(np.indices(shape), -1) * dx
    centre = np.array([1.1, 1.0, 1.0])  # moved by v * (t + dt)
    r = x - centre
    dist = np.linalg.norm(r, axis=-1)
    inside, outside = dist < 0.5 - 1e-9, dist > 0.5 + 1e-9  # nodes on the sphere: round-off
    rigid = np.array([0.2, 0, 0]) + np.cross(omega, r)
    assert np.allclose(v[inside], rigid[inside], atol=1e-14)
    assert np.all(v[outside] == 0.0)


def test_signed_distance_of_shapes_and_rotating_box():
    from hpcmpm.boundaries.colliders import BOX, CYLINDER, signed_distance
    size = np.array([1.0, 2.0, 3.0])
    assert np.allclose(signed_distance(BOX, size, 2.0, 0.0, 0.0), (1.0, 1.0, 0.0, 0.0))
    assert np.allclose(signed_distance(BOX, size, 0.0, 0.0, -2.5), (-0.5, 0.0, 0.0, -1.0))
    assert np.allclose(signed_distance(CYLINDER, np.array([1.0, 2.0, 0]), 0.0, 3.0, 0.0),
                       (2.0, 0.0, 1.0, 0.0))
    # A box spinning about z at pi/2 per unit time: at t=1 its long axis (y) lies along x.
    c = Collider(collider("box", {"center": [0.0, 0.0, 0.0], "half_extents": [0.1, 1.0, 0.1]},
                          omega=[0.0, 0.0, np.pi / 2]), 3)
    R = c.rotation(1.0)
    assert np.allclose(R @ np.array([0, 1.0, 0]), [-1.0, 0, 0], atol=1e-12)


def test_prescribed_marks_cover_exactly_the_support_and_impose_rotation():
    rng = np.random.default_rng(2)
    dx, order = 0.1, 2
    x = rng.uniform(0.3, 0.7, size=(50, 2))
    tags = np.where(np.arange(50) < 20, 0, -1).astype(np.int32)
    origin = np.zeros(2, dtype=np.int64)
    block = np.array([12, 12, 1])
    marks = np.zeros(12 * 12)
    scatter_marks(x, tags, 0, order, dx, np.zeros(2), origin, block, marks)
    base, _, _ = evaluate(x[:20] / dx, order, 1 / dx)
    expected = np.zeros((12, 12))
    for b in base:
        expected[b[0]:b[0] + 3, b[1]:b[1] + 3] += 1
    assert np.array_equal(marks.reshape(12, 12), expected)
    spec = types.SimpleNamespace(region={"lower": [0, 0], "upper": [1, 1]}, velocity=[0.1, 0],
                                 angular_velocity=2.0, center=[0.5, 0.5])
    s = PrescribedSet(spec, 0, 2)
    v = np.zeros((12, 12, 2))
    from hpcmpm.boundaries.prescribed import impose_rigid_velocity
    impose_rigid_velocity(v.reshape(-1, 2), marks, block, np.zeros(3, np.int64), dx,
                          np.zeros(3), s.centre(0.0), s.velocity, s.omega)
    pos = np.stack(np.indices((12, 12)), -1) * dx - 0.5
    rigid = np.stack([0.1 - 2.0 * pos[..., 1], 2.0 * pos[..., 0]], -1)
    on = marks.reshape(12, 12) > 0
    assert np.allclose(v[on], rigid[on], atol=1e-15)
    assert np.all(v[~on] == 0)

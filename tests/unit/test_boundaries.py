"""Walls, colliders and prescribed sets against their analytic formulas.

Walls and colliders: Stomakhin 2013 §8 projection (sticky / slip / separate with Coulomb
friction). Prescribed sets: node tags equal the B-spline support of the marked particles, and
the rigid field they impose is reproduced exactly by G2P (partition of unity + linear
completeness, 000 §3.2)."""

import types

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.boundaries import Collider, PrescribedSet, build_boundaries
from hpcmpm.boundaries.contact import SEPARATE, SLIP, STICKY, project
from hpcmpm.boundaries.prescribed import scatter_marks
from hpcmpm.boundaries.walls import Walls
from hpcmpm.kernels.shape import evaluate

MU = 0.4


def face(condition, friction=0.0):
    return types.SimpleNamespace(condition=condition, friction=friction)


def expected_projection(v, n, condition, mu):
    """The analytic projection of relative velocities v (m, d) against unit normal n (d,),
    written independently of the kernel: |v_t| -> max(|v_t| - mu |v_n|, 0), same direction."""
    vn = v @ n
    vt = v - vn[:, None] * n
    if condition == "sticky":
        return np.zeros_like(v)
    if condition == "slip":
        return vt
    speed = np.linalg.norm(vt, axis=1)
    new_speed = np.maximum(speed - mu * np.abs(vn), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        projected = np.where(speed[:, None] > 0, vt * (new_speed / speed)[:, None], 0.0)
    return np.where((vn < 0)[:, None], projected, v)


# -- the shared projection ---------------------------------------------------------------------
def test_projection_formulas():
    # Moving into the obstacle (normal +y) with v = (3, -1, 0).
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, STICKY, 0.0) == (0.0, 0.0, 0.0)
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SLIP, 0.5) == (3.0, 0.0, 0.0)
    # Coulomb: tangential speed 3 loses friction * |v_n| = 0.5 * 1.
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 0.5) == (2.5, 0.0, 0.0)
    # Friction large enough to stop it: stopped, never reversed.
    assert project(3.0, -1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 5.0) == (0.0, 0.0, 0.0)
    # Separating: untouched.
    assert project(3.0, 1.0, 0.0, 0.0, 1.0, 0.0, SEPARATE, 0.5) == (3.0, 1.0, 0.0)


# -- walls -------------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("condition", ["sticky", "slip", "separate"])
def test_each_wall_face_projects_the_nodes_on_or_beyond_it(dim, condition):
    n_cells, origin, width = 6, -2, 11  # the block holds global nodes -2 .. 8
    idx = np.indices((width,) * dim) + origin
    rng = np.random.default_rng(dim)
    for f in range(2 * dim):
        axis, upper = divmod(f, 2)
        faces = [face("slip")] * (2 * dim)
        faces[f] = face(condition, MU)
        v = rng.normal(size=(width,) * dim + (dim,))
        out = v.copy()
        Walls(faces, [n_cells] * dim).apply(out, np.full(dim, origin), 0.1, np.zeros(dim),
                                            0.0, 0.01)
        beyond = [(idx[a] <= 0) | (idx[a] >= n_cells) for a in range(dim)]
        this = (idx[axis] >= n_cells) if upper else (idx[axis] <= 0)
        only_this = this & ~np.any([beyond[a] for a in range(dim) if a != axis], axis=0)
        normal = np.zeros(dim)
        normal[axis] = -1.0 if upper else 1.0  # the wall's outward normal points inwards
        want = expected_projection(v[only_this], normal, condition, MU)
        np.testing.assert_allclose(out[only_this], want, rtol=0, atol=1e-15)
        inside = ~np.any(beyond, axis=0)
        assert np.array_equal(out[inside], v[inside])
        if condition == "separate":
            inward = only_this & (v[..., axis] * normal[axis] >= 0)
            assert inward.any() and np.array_equal(out[inward], v[inward])
            # Tangential speed reduced by exactly mu |v_n| (or to zero), never reversed.
            into = only_this & (v[..., axis] * normal[axis] < 0)
            tangential = [a for a in range(dim) if a != axis]
            before = np.linalg.norm(v[into][:, tangential], axis=1)
            after = np.linalg.norm(out[into][:, tangential], axis=1)
            np.testing.assert_allclose(
                after, np.maximum(before - MU * np.abs(v[into][:, axis]), 0.0), atol=1e-14)
            assert np.all(np.sum(out[into][:, tangential] * v[into][:, tangential], 1) >= 0)
            assert np.all(out[into][:, axis] == 0.0)


def test_walls_skip_massless_nodes_and_handle_blocks_away_from_walls():
    v = np.ones((5, 5, 2))
    mass = np.ones((5, 5))
    mass[0, 2] = 0.0
    walls = Walls([face("sticky")] * 4, [10, 10])
    walls.apply(v, np.array([0, 3]), 0.1, np.zeros(2), 0.0, 0.01, mass)
    assert np.all(v[0, [0, 1, 3, 4]] == 0.0) and np.all(v[0, 2] == 1.0)
    assert np.all(v[1:] == 1.0)  # nodes 1..4 along x, 3..7 along y: no other wall
    far = np.ones((4, 4, 4, 3))
    Walls([face("sticky")] * 6, [20] * 3).apply(far, np.full(3, 5), 0.1, np.zeros(3), 0, 0.1)
    assert np.all(far == 1.0)


def test_walls_do_not_act_on_the_faces_of_periodic_axes():
    v = np.ones((12, 12, 2))
    Walls([face("sticky")] * 4, [10, 10], periodic=(0,)).apply(v, np.array([-1, -1]), 0.1,
                                                               np.zeros(2), 0.0, 0.01)
    assert np.all(v[:, [0, 1, 11]] == 0.0)  # y faces: nodes -1, 0 and 10 along y
    assert np.all(v[:, 2:11] == 1.0)  # x faces (nodes -1, 0, 10 along x) untouched


# -- colliders ---------------------------------------------------------------------------------
def collider_spec(shape, params, condition="sticky", velocity=(), omega=None, friction=0.0,
                  start=0.0, end=np.inf):
    return types.SimpleNamespace(name="c", shape=shape, params=params, condition=condition,
                                 friction=friction, velocity=velocity, angular_velocity=omega,
                                 start=start, end=end)


def rot2(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def rot_x(angle):
    out = np.eye(3)
    out[1:, 1:] = rot2(angle)
    return out


def box_sdf(y, h):
    """Exact signed distance of the box |y_a| <= h_a and its gradient (body frame)."""
    q = np.abs(y) - h
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    phi = np.where(q.max(1) > 0, outside, q.max(1))
    inside_n = np.eye(y.shape[1])[q.argmax(1)] * np.sign(y)
    with np.errstate(invalid="ignore"):
        outside_n = np.maximum(q, 0) * np.sign(y) / outside[:, None]
    return phi, np.where((q.max(1) > 0)[:, None], outside_n, inside_n)


def analytic_cases():
    """(name, collider, points, phi, normal) with phi and normal from independent formulas."""
    rng = np.random.default_rng(7)
    cases = []
    for dim in (2, 3):
        x = rng.uniform(-1, 1, size=(400, dim))
        c = np.full(dim, 0.1)
        d = x - c
        r = np.linalg.norm(d, axis=1)
        cases.append((f"sphere{dim}", Collider(collider_spec(
            "sphere", {"center": c, "radius": 0.5}), dim), x, r - 0.5, d / r[:, None]))
        n = np.arange(1.0, dim + 1)
        n /= np.linalg.norm(n)
        p = np.full(dim, -0.2)
        cases.append((f"half_space{dim}", Collider(collider_spec(
            "half_space", {"point": p, "normal": n * 3}), dim), x, (x - p) @ n,
            np.tile(n, (len(x), 1))))
    # A ceiling in 3D: normal -z, antiparallel to the body frame's z (the one rotation that
    # `rotation_taking_z_to` cannot build from a cross product).
    x = rng.uniform(-1, 1, size=(400, 3))
    cases.append(("half_space3_down", Collider(collider_spec(
        "half_space", {"point": [0.0, 0.0, 0.3], "normal": [0.0, 0.0, -2.0]}), 3), x,
        0.3 - x[:, 2], np.tile([0.0, 0.0, -1.0], (len(x), 1))))
    # 2D box turned by 0.3 rad, half extents larger than 1 (deep inside must stay in-plane).
    x = rng.uniform(-4, 4, size=(400, 2))
    R = rot2(0.3)
    phi, m = box_sdf((x - [0.5, 0.0]) @ R, np.array([1.5, 2.5]))
    cases.append(("box2", Collider(collider_spec("box", {
        "center": [0.5, 0.0], "half_extents": [1.5, 2.5], "rotation": 0.3}), 2), x, phi, m @ R.T))
    # 3D box turned by 0.7 rad about x (rotation vector along x).
    x = rng.uniform(-1.5, 1.5, size=(400, 3))
    R = rot_x(0.7)
    h = np.array([0.3, 0.6, 0.9])
    phi, m = box_sdf(x @ R, h)
    cases.append(("box3", Collider(collider_spec("box", {
        "center": [0.0] * 3, "half_extents": h, "rotation": [0.7, 0, 0]}), 3), x, phi, m @ R.T))
    # Cylinder along x (body z -> world x): radial in (y, z), axial along x.
    x = rng.uniform(-1.5, 1.5, size=(400, 3))
    rho = np.linalg.norm(x[:, 1:], axis=1)
    q = np.stack([rho - 0.5, np.abs(x[:, 0]) - 1.0], 1)
    phi2, m2 = box_sdf(np.stack([rho, x[:, 0]], 1), np.array([0.5, 1.0]))
    radial = np.concatenate([np.zeros((400, 1)), x[:, 1:] / rho[:, None]], 1)
    normal = m2[:, :1] * radial + m2[:, 1:] * np.array([1.0, 0, 0])
    assert np.allclose(phi2, np.where(q.max(1) > 0, np.linalg.norm(np.maximum(q, 0), axis=1),
                                      q.max(1)))
    cases.append(("cylinder3", Collider(collider_spec("cylinder", {
        "center": [0.0] * 3, "axis": [2.0, 0, 0], "radius": 0.5, "half_length": 1.0}), 3),
        x, phi2, normal))
    return cases


@pytest.mark.parametrize("case", analytic_cases(), ids=lambda c: c[0])
def test_collider_phi_and_normal_match_analytic_values(case):
    _, col, x, phi, normal = case
    got_phi, got_n = col.level_set(x, 0.0)
    assert (got_phi < 0).any() and (got_phi > 0).any()  # the samples straddle the surface
    np.testing.assert_allclose(got_phi, phi, atol=1e-14)
    np.testing.assert_allclose(got_n, normal, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(got_n, axis=1), 1.0, atol=1e-14)


@pytest.mark.parametrize("case", analytic_cases(), ids=lambda c: c[0])
def test_collider_normal_is_the_gradient_of_phi(case):
    """Central differences of phi equal the normal wherever phi is smooth: points whose
    normal changes by less than 1e-2 over a 1e-3 step (away from edges, ridges and the
    medial surface, where phi has a kink)."""
    _, col, x, _, _ = case
    dim, h = x.shape[1], 1e-6
    _, normal = col.level_set(x, 0.0)
    smooth = np.ones(len(x), bool)
    for a in range(dim):
        for s in (-1e-3, 1e-3):
            smooth &= np.all(np.abs(col.level_set(x + s * np.eye(dim)[a], 0.0)[1] - normal)
                             < 1e-2, axis=1)
    assert smooth.sum() > len(x) // 2
    grad = np.stack([(col.level_set(x + h * e, 0.0)[0] - col.level_set(x - h * e, 0.0)[0])
                     / (2 * h) for e in np.eye(dim)], 1)
    np.testing.assert_allclose(grad[smooth], normal[smooth], atol=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_kinematic_sphere_imposes_rigid_velocity_inside_only(dim):
    dx, t, dt = 0.1, 0.3, 0.2
    shape = (21,) * dim
    omega = np.array([0.0, 1.0, 2.0]) if dim == 3 else 2.0
    v_lin = np.array([0.2, -0.1, 0.05])[:dim]
    c = Collider(collider_spec("sphere", {"center": [1.0] * dim, "radius": 0.5},
                               velocity=v_lin, omega=omega), dim)
    v = np.zeros(shape + (dim,))
    c.apply(v, np.zeros(dim, np.int64), dx, np.zeros(dim), t, dt, np.ones(shape))
    x = np.stack(np.indices(shape), -1) * dx
    centre = 1.0 + v_lin * (t + dt)  # placed at the end of the step
    assert np.allclose(c.position(t + dt), centre)
    r = x - centre
    dist = np.linalg.norm(r, axis=-1)
    inside, outside = dist < 0.5 - 1e-9, dist > 0.5 + 1e-9  # nodes on the sphere: round-off
    if dim == 3:
        rigid = v_lin + np.cross(omega, r)
    else:
        rigid = v_lin + omega * np.stack([-r[..., 1], r[..., 0]], -1)
    assert inside.sum() > 50
    np.testing.assert_allclose(v[inside], rigid[inside], atol=1e-14)
    assert np.all(v[outside] == 0.0)


def test_collider_acts_only_in_its_time_window_and_on_massive_nodes():
    spec = collider_spec("sphere", {"center": [0.5, 0.5], "radius": 0.3}, start=1.0, end=2.0)
    c = Collider(spec, 2)
    v = np.ones((11, 11, 2))
    mass = np.ones((11, 11))
    mass[5, 5] = 0.0
    c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 0.5, 0.1, mass)  # t + dt = 0.6
    assert np.all(v == 1.0)
    c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 1.5, 0.1, mass)
    assert np.all(v[5, 5] == 1.0) and np.all(v[5, 4] == 0.0) and np.all(v[0, 0] == 1.0)


def test_separating_moving_collider_projects_the_relative_velocity():
    # Floor y <= 0.55 rising at 1 m/s with friction; nodes below the floor move down at 1 and
    # sideways at 3: relative normal velocity -2 is removed, tangential 3 -> 3 - mu * 2.
    mu = 0.25
    c = Collider(collider_spec("half_space", {"point": [0.0, 0.55], "normal": [0.0, 1.0]},
                               "separate", velocity=[0.0, 1.0], friction=mu), 2)
    v = np.zeros((11, 11, 2))
    v[..., 0], v[..., 1] = 3.0, -1.0
    c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 0.0, 0.1)  # floor at 0.65
    inside = np.arange(11) * 0.1 < 0.65
    np.testing.assert_allclose(v[:, inside], np.broadcast_to([3.0 - mu * 2.0, 1.0],
                                                             v[:, inside].shape), atol=1e-15)
    assert np.all(v[:, ~inside] == [3.0, -1.0])



def test_constrain_records_the_normal_where_the_collider_pushes_in_relative_terms():
    # The semi-implicit mask of the same rising floor (y <= 0.55 at 1 m/s, separate): it is
    # placed at t + dt, so at y <= 0.65, and nodes there move up at 0.5 m/s, slower than the
    # floor. Relative normal velocity 0.5 - 1 = -0.5 < 0: the floor pushes them, and
    # `constrain` fixes their normal (count 1, basis row (0, 1, 0)). Judged by the absolute
    # velocity (+0.5, moving away) the mask would be empty.
    c = Collider(collider_spec("half_space", {"point": [0.0, 0.55], "normal": [0.0, 1.0]},
                               "separate", velocity=[0.0, 1.0]), 2)
    v = np.zeros((11, 11, 2))
    v[..., 1] = 0.5
    basis = np.zeros((11, 11, 1, 3, 3))
    count = np.zeros((11, 11, 1), np.int64)
    c.constrain(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 0.0, 0.1, np.ones((11, 11)),
                basis, count)
    inside = np.arange(11) * 0.1 < 0.65  # y = 0 .. 0.6 (the floor at 0.65 at t + dt)
    assert np.all(count[:, inside] == 1) and np.all(count[:, ~inside] == 0)
    np.testing.assert_array_equal(basis[:, inside, 0, 0],
                                  np.broadcast_to([0.0, 1.0, 0.0], basis[:, inside, 0, 0].shape))
    assert np.all(v[..., 1] == 0.5)  # recording leaves the trial velocity alone


@pytest.mark.parametrize("dim", [2, 3])
def test_rotated_sticky_box_stops_every_node_inside_it(dim):
    # A long thin box (half extents 0.5 x 0.1) turned 1.2 rad reaches well outside its
    # unrotated bounding box (2D: [0.5, 1.5] x [0.9, 1.1]): the nodes searched must cover the
    # rotated box. Measured: 19 (2D) / 38 (3D) nodes have phi <= 0; a search box that
    # ignores the rotation misses 8 / 16 of them.
    if dim == 2:
        spec = collider_spec("box", {"center": [1.0, 1.0], "half_extents": [0.5, 0.1],
                                     "rotation": 1.2})
    else:
        spec = collider_spec("box", {"center": [1.0, 1.0, 1.0], "half_extents": [0.1, 0.5, 0.1],
                                     "rotation": [1.2, 0, 0]})
    c = Collider(spec, dim)
    shape = (21,) * dim
    v = np.ones(shape + (dim,))
    c.apply(v, np.zeros(dim, np.int64), 0.1, np.zeros(dim), 0.0, 0.0, np.ones(shape))
    x = np.stack(np.indices(shape), -1).reshape(-1, dim) * 0.1
    phi, _ = c.level_set(x, 0.0)
    inside = (phi <= 0.0).reshape(shape)
    assert inside.sum() == 19 * (dim - 1)
    assert np.all(v[inside] == 0.0)
    assert np.all(v[~inside] == 1.0)

def test_a_collider_far_larger_than_the_domain_still_acts():
    """A sticky box of half-extents [0.1, 2**63]: its node indices along y exceed int64.
    Their cast gave INT64_MIN, an empty node box, and the collider stopped no node (a fuzzed
    hb_mixer_2d). It must stop every node of the strip |x - 1| <= 0.1, at every y."""
    c = Collider(collider_spec("box", {"center": [1.0, 1.0],
                                       "half_extents": [0.1, 9223372036854775808.0]}), 2)
    shape = (21, 21)
    v = np.ones(shape + (2,))
    with np.errstate(all="raise"):  # no invalid cast either
        c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 0.0, 0.0, np.ones(shape))
    x = np.stack(np.indices(shape), -1).reshape(-1, 2) * 0.1
    phi, _ = c.level_set(x, 0.0)
    strip = (phi <= 0.0).reshape(shape)
    assert strip[10].all() and strip.sum() % 21 == 0  # whole columns: every y
    assert np.all(v[strip] == 0.0)
    assert np.all(v[~strip] == 1.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_rotating_box_carries_body_points(dim):
    t = 0.8
    angle0, rate = 0.4, 1.3
    if dim == 2:
        spec = collider_spec("box", {"center": [0.2, 0.1], "half_extents": [0.5, 0.1],
                                     "rotation": angle0}, velocity=[0.5, 0.0], omega=rate)
        R_expected = rot2(angle0 + rate * t)
    else:
        spec = collider_spec("box", {"center": [0.2, 0.1, 0.0], "half_extents": [0.1, 0.5, 0.1],
                                     "rotation": [angle0, 0, 0]}, velocity=[0.5, 0, 0],
                             omega=[rate, 0, 0])
        R_expected = rot_x(angle0 + rate * t)
    c = Collider(spec, dim)
    np.testing.assert_allclose(c.rotation(t)[:dim, :dim], R_expected, atol=1e-14)
    body = np.array([0.45, 0.08]) if dim == 2 else np.array([0.08, 0.45, 0.0])
    tip = c.position(t) + R_expected @ body  # a point fixed in the body frame
    phi, _ = c.level_set(tip[None], t)
    np.testing.assert_allclose(phi, -0.02, atol=1e-14)  # 0.02 from the nearest face
    assert c.level_set(tip[None], 0.0)[0][0] > 0.0  # the box was elsewhere at t = 0


def test_build_boundaries_from_a_scene():
    scene = types.SimpleNamespace(
        dim=2, dx=0.1, domain_lo=(0.0, 0.0), domain_hi=(1.0, 2.0),
        walls=types.SimpleNamespace(faces=(face("sticky"),) * 4),
        colliders=(collider_spec("sphere", {"center": [0.5, 0.5], "radius": 0.1}),),
        prescribed=())
    walls, col = build_boundaries(scene)
    assert isinstance(walls, Walls) and list(walls.n_cells) == [10, 20]
    assert isinstance(col, Collider)


# -- prescribed sets ---------------------------------------------------------------------------
def brute_force_counts(x, sets, set_index, order, dx, origin, shape):
    """Per node, the number of particles of set ``set_index`` whose support holds it, from the
    definition of the support (ARCHITECTURE.md)."""
    xi = x / dx
    base = np.floor(xi - 0.5) if order == 2 else np.floor(xi) - 1
    counts = np.zeros(shape)
    for b, s in zip(base.astype(int), sets):
        if s != set_index:
            continue
        region = tuple(slice(b[a] - origin[a], b[a] - origin[a] + order + 1)
                       for a in range(len(b)))
        counts[region] += 1
    return counts


def marks_of(x, sets, set_index, order, dx, origin, shape):
    dim = x.shape[1]
    marks = np.zeros(shape + (1,) * (3 - dim))
    org3 = np.zeros(3, np.int64)
    org3[:dim] = origin
    scatter_marks(x, sets, set_index, order, dx, np.zeros(3), org3, marks)
    return marks.reshape(shape)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [2, 3])
def test_scatter_marks_counts_exactly_the_support(dim, order):
    rng = np.random.default_rng(order + dim)
    dx, origin, shape = 0.1, np.full(dim, -1), (14,) * dim
    x = rng.uniform(0.2, 1.0, size=(60, dim))
    sets = rng.choice([-1, 0, 1], size=60).astype(np.int32)  # two sets that overlap
    for set_index in (0, 1):
        marks = marks_of(x, sets, set_index, order, dx, origin, shape)
        assert np.array_equal(marks, brute_force_counts(x, sets, set_index, order, dx, origin,
                                                        shape))
        assert (marks > 0).any() and (marks == 0).any()


def prescribed_spec(dim, velocity, omega, center):
    return types.SimpleNamespace(region={"lower": [0.3] * dim, "upper": [0.6] * dim},
                                 velocity=velocity, angular_velocity=omega, center=center)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("order", [2, 3])
def test_prescribed_rigid_motion_is_reproduced_exactly(dim, order):
    rng = np.random.default_rng(11)
    dx, t = 0.1, 0.7
    omega = 2.0 if dim == 2 else np.array([0.5, -1.0, 2.0])
    v_lin = np.array([0.1, -0.2, 0.3])[:dim]
    centre0 = np.full(dim, 0.45)
    spec = prescribed_spec(dim, v_lin, omega, centre0)
    s = PrescribedSet(spec, 0, dim)
    x = rng.uniform(0.0, 1.0, size=(400, dim))
    chosen = s.select(x)
    assert np.array_equal(chosen, np.all((x >= 0.3) & (x <= 0.6), axis=1))
    index = np.where(chosen, 0, -1).astype(np.int32)
    shape = (14,) * dim
    origin = np.full(dim, -2)
    marks = marks_of(x, index, 0, order, dx, origin, shape)
    free = rng.normal(size=shape + (dim,))
    v = free.copy()
    # The rigid field is centred at c(t), t the start of the step (PrescribedSet.apply).
    s.apply(v, origin, dx, np.zeros(dim), t, 0.01, {s.mark_field: marks})
    nodes = (np.stack(np.indices(shape), -1) + origin) * dx
    r = nodes - (centre0 + v_lin * t)
    if dim == 3:
        rigid = v_lin + np.cross(omega, r)
    else:
        rigid = v_lin + omega * np.stack([-r[..., 1], r[..., 0]], -1)
    on = marks > 0
    np.testing.assert_allclose(v[on], rigid[on], atol=1e-15)
    assert np.array_equal(v[~on], free[~on])
    # G2P of the marked particles: v_p = sum_i w_ip v_i is the rigid velocity at x_p exactly
    # (their whole support is tagged), though the other nodes hold random velocities.
    base, w, _ = evaluate(x[chosen] / dx, order, 1 / dx)
    stencil = np.stack(np.meshgrid(*[np.arange(order + 1)] * dim, indexing="ij"), -1)
    stencil = stencil.reshape(-1, dim)
    for p, (b, wp) in enumerate(zip(base, w)):
        nodes_p = b + stencil - origin
        weight = np.prod(wp[np.arange(dim), stencil], axis=1)
        vp = weight @ v[tuple(nodes_p.T)]
        rp = x[chosen][p] - (centre0 + v_lin * t)
        want = v_lin + (np.cross(omega, rp) if dim == 3 else omega * np.array([-rp[1], rp[0]]))
        np.testing.assert_allclose(vp, want, atol=1e-13)


def rot_z(angle):
    out = np.eye(3)
    out[:2, :2] = rot2(angle)
    return out


def test_spin_about_another_axis_than_the_initial_rotation_turns_in_the_world_frame():
    """R(t) = exp(t [omega]x) R0: the spin acts about a world axis after the initial turn.
    3D: a box turned about x (R0), spinning about z; 2D: a half-space (R0 takes body z to
    the in-plane normal) spinning about z, so its normal turns with it. Composing the other
    way (R0 exp(t [omega]x)) spins about a body axis: the 3D box ends elsewhere and the
    half-space spins about its own normal, i.e. does not turn at all."""
    t, angle0, rate = 0.8, 0.4, 1.3
    box = Collider(collider_spec("box", {"center": [0.2, 0.1, 0.0],
                                         "half_extents": [0.1, 0.5, 0.1],
                                         "rotation": [angle0, 0, 0]}, omega=[0, 0, rate]), 3)
    R = rot_z(rate * t) @ rot_x(angle0)
    np.testing.assert_allclose(box.rotation(t), R, atol=1e-14)
    tip = box.position(t) + R @ np.array([0.08, 0.45, 0.0])  # fixed in the body frame
    np.testing.assert_allclose(box.level_set(tip[None], t)[0], -0.02, atol=1e-14)
    floor = Collider(collider_spec("half_space", {"point": [0.5, 0.5], "normal": [0.0, 1.0]},
                                   omega=rate), 2)
    normal = rot2(rate * t) @ [0.0, 1.0]
    x = np.array([[0.9, 0.7], [0.1, 0.2], [0.5, 1.5]])
    phi, n = floor.level_set(x, t)
    np.testing.assert_allclose(phi, (x - 0.5) @ normal, atol=1e-14)
    np.testing.assert_allclose(n, np.tile(normal, (3, 1)), atol=1e-14)


def test_sticky_cylinder_stops_every_node_inside_it():
    """An oblique squat cylinder (radius 0.45, half length 0.2) on a 21^3 grid: exactly the
    nodes with rho <= r and |axial| <= h (written out here) are stopped. The nodes searched
    must span the radius across the axis too: a search box from the axis segment alone
    (plus its node of margin) misses the inside nodes more than 0.2 from the centre in x."""
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    c = Collider(collider_spec("cylinder", {"center": [1.0, 1.0, 1.0], "axis": axis * 3,
                                            "radius": 0.45, "half_length": 0.2}), 3)
    shape = (21,) * 3
    v = np.ones(shape + (3,))
    c.apply(v, np.zeros(3, np.int64), 0.1, np.zeros(3), 0.0, 0.0, np.ones(shape))
    r = np.stack(np.indices(shape), -1) * 0.1 - 1.0
    along = r @ axis
    rho = np.linalg.norm(r - along[..., None] * axis, axis=-1)
    # Margins of 1e-9 keep nodes within round-off of the surface out of both sets.
    inside = (rho < 0.45 - 1e-9) & (np.abs(along) < 0.2 - 1e-9)
    outside = (rho > 0.45 + 1e-9) | (np.abs(along) > 0.2 + 1e-9)
    assert inside.sum() > 50
    assert np.all(v[inside] == 0.0)
    assert np.all(v[outside] == 1.0)


@pytest.mark.parametrize("angle", [2.5, -1.2, 4.0])
def test_sticky_box_at_any_angle_stops_exactly_the_nodes_inside(angle):
    """A thin 2D box (half extents 0.5 x 0.1) at angles whose rotation has negative entries:
    the nodes stopped are exactly those inside by the box's own formula (body coordinates
    |y_a| <= h_a, written out here), whatever the signs of cos and sin."""
    c = Collider(collider_spec("box", {"center": [1.0, 1.0], "half_extents": [0.5, 0.1],
                                       "rotation": angle}), 2)
    shape = (21, 21)
    v = np.ones(shape + (2,))
    c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), 0.0, 0.0, np.ones(shape))
    y = (np.stack(np.indices(shape), -1) * 0.1 - 1.0) @ rot2(angle)  # body frame: R^T r
    q = np.abs(y) - [0.5, 0.1]
    inside, outside = np.all(q < -1e-9, axis=-1), np.any(q > 1e-9, axis=-1)  # round-off
    assert inside.sum() > 10
    assert np.all(v[inside] == 0.0)
    assert np.all(v[outside] == 1.0)


def test_collider_window_is_judged_at_the_end_of_the_step():
    """The collider is placed and its window checked at t + dt (`Collider.apply`): a step
    from 0.95 to 1.05 meets a collider that starts at 1.0, a step from 1.95 to 2.05 does
    not meet one that ends at 2.0."""
    spec = collider_spec("sphere", {"center": [0.5, 0.5], "radius": 0.3}, start=1.0, end=2.0)
    c = Collider(spec, 2)
    for t, acts in [(0.95, True), (1.95, False)]:
        v = np.ones((11, 11, 2))
        c.apply(v, np.zeros(2, np.int64), 0.1, np.zeros(2), t, 0.1)
        assert (v[5, 5] == 0.0).all() == acts and np.all(v[0, 0] == 1.0)


def test_separate_node_at_rest_relative_to_the_obstacle_is_not_constrained():
    """`constrain` fixes the normal only where the node moves into the obstacle (v.n < 0),
    the same rule as `project`, which leaves v.n = 0 untouched: a node at rest on a separate
    floor (v = 0, the start of every resting contact) stays free to lift off."""
    walls = Walls([face("separate")] * 4, [4, 4])
    v = np.zeros((6, 6, 2))
    v[1, 3] = [0.0, -1.0]  # global node (0, 2): on the x-lower wall, sliding along it
    v[3, 1] = [0.0, -1.0]  # global node (2, 0): on the y-lower wall, moving into it
    basis = np.zeros((6, 6, 1, 3, 3))
    count = np.zeros((6, 6, 1), np.int64)
    walls.constrain(v, np.array([-1, -1]), 0.25, np.zeros(2), 0.0, 0.01, np.ones((6, 6)),
                    basis, count)
    c = count[..., 0]
    assert c[3, 1] == 1 and np.allclose(basis[3, 1, 0, 0], [0.0, 1.0, 0.0])
    c[3, 1] = 0
    assert np.all(c == 0), np.argwhere(c)  # every other wall node has v.n = 0


def test_prescribed_regions_are_closed_and_the_first_matching_set_wins():
    """`select` keeps particles exactly on the region's faces (a closed box), and where two
    regions overlap `mark_prescribed_particles` gives the particle to the earlier set."""
    from hpcmpm.boundaries import mark_prescribed_particles

    spec = prescribed_spec(2, (), None, None)  # region [0.3, 0.6]^2
    s = PrescribedSet(spec, 0, 2)
    x = np.array([[0.3, 0.3], [0.6, 0.6], [0.3, 0.6], [0.45, 0.6], [0.6 + 1e-12, 0.45],
                  [0.45, 0.3 - 1e-12]])
    np.testing.assert_array_equal(s.select(x), [True, True, True, True, False, False])
    second = types.SimpleNamespace(region={"lower": [0.5, 0.5], "upper": [0.9, 0.9]},
                                   velocity=(), angular_velocity=None, center=None)
    scene = types.SimpleNamespace(dim=2, prescribed=[spec, second])
    particles = {"x": np.array([[0.55, 0.55], [0.8, 0.8], [0.1, 0.1], [0.4, 0.4]]),
                 "prescribed": np.zeros(4, np.int32)}
    mark_prescribed_particles(scene, particles)
    np.testing.assert_array_equal(particles["prescribed"], [0, 1, -1, 0])


@pytest.mark.parametrize("dim", [2, 3])
def test_prescribed_nodes_are_fixed_in_every_direction(dim):
    """The semi-implicit mask of a prescribed set: every marked node has all dim directions
    fixed (the clamp's values come from `apply`), unmarked nodes none."""
    s = PrescribedSet(prescribed_spec(dim, (), None, None), 0, dim)
    shape = (5,) * dim
    marks = np.zeros(shape)
    marks[(1,) * dim] = 2.0
    marks[(3,) * dim] = 1.0
    basis = np.zeros(shape + (1,) * (3 - dim) + (3, 3))
    count = np.zeros(shape + (1,) * (3 - dim), np.int64)
    s.constrain(np.zeros(shape + (dim,)), np.zeros(dim, np.int64), 0.1, np.zeros(dim), 0.0,
                0.01, {s.mark_field: marks}, basis, count)
    on = (marks > 0).reshape(count.shape)
    assert np.all(count[on] == dim) and np.all(count[~on] == 0)
    # The first dim rows span the dim axes: the projector onto them is the identity there.
    rows = basis[on][:, :dim, :dim]
    np.testing.assert_array_equal(np.einsum("nki,nkj->nij", rows, rows),
                                  np.broadcast_to(np.eye(dim), rows.shape))


MIXED_PUSH = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.05
gravity = [0.0, 0.0]
end_time = 0.02
%s
[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1000.0
E = 1000.0
nu = 0.3

[[materials]]
name = "steel"
type = "peridynamic"
model = "pmb"
integration = "pd"
plane = "strain"
density = 1000.0
E = 1000.0
nu = 0.25

[[bodies]]
name = "block"
material = "rubber"
shape = "box"
lower = [0.3, 0.3]
upper = [0.5, 0.7]

[[bodies]]
name = "pusher"
material = "steel"
shape = "box"
lower = [0.5, 0.3]
upper = [0.7, 0.7]

[[prescribed]]
name = "push"
region = { lower = [0.5, 0.3], upper = [0.7, 0.7] }
velocity = [0.5, 0.0]
"""


@pytest.mark.parametrize("integrator", ["explicit", "semi_implicit"])
def test_an_off_grid_pd_set_does_not_clamp_the_nodes_of_an_mpm_body_beside_it(integrator):
    """An off-grid PD body in a prescribed set is moved per particle (pd/boundary.py); it has
    no grid nodes, so its set marks none. Before, its particles' supports marked the nodes
    of the MPM block touching it, and the whole block (128 of 128 particles) took the set's
    velocity 0.5; at rest, without gravity or stress, it must stay exactly at rest."""
    from hpcmpm.runner import simulate
    from hpcmpm.scene import parse_scene

    text = MIXED_PUSH % f'integrator = "{integrator}"'
    sim = simulate(parse_scene(text, path="<mixed push>"))
    p = sim.particles
    block, pusher = p["group"] == 0, p["group"] == 1
    assert sim.step_index >= 1 and block.sum() == 128
    assert np.all(p["v"][pusher] == [0.5, 0.0])
    assert np.all(p["v"][block] == 0.0)


def test_off_grid_pd_beside_grid_bodies_is_warned_about(caplog):
    """Off-grid PD bodies and the grid's bodies pass through each other: a scene with both
    says so once, naming the material; a scene of off-grid PD bodies alone does not."""
    from hpcmpm.runner import simulate
    from hpcmpm.scene import load_scene, parse_scene

    with caplog.at_level("WARNING", logger="hpcmpm"):
        simulate(parse_scene(MIXED_PUSH % "", path="<mixed push>"), end_time=1e-3)
    said = [r.getMessage() for r in caplog.records if "pass through" in r.getMessage()]
    assert said == ["<mixed push>: materials[1]: warning: material 'steel' (integration = "
                    "\"pd\") moves off the grid: its bodies and the grid's bodies pass through "
                    "each other (no contact); integration = \"grid\" couples them through the "
                    "grid"]
    caplog.clear()
    with caplog.at_level("WARNING", logger="hpcmpm"):
        simulate(load_scene("inputs/kalthoff_winkler_2d.toml"), end_time=1e-6)
    assert not [r for r in caplog.records if "pass through" in r.getMessage()]
    # An off-grid PD material that no body uses has no bodies to pass through anything.
    unused = Path("inputs/disks_2d.toml").read_text() + (
        '\n[[materials]]\nname = "spare"\ntype = "peridynamic"\ndensity = 1000.0\n'
        'E = 1e5\nnu = 0.25\n')
    caplog.clear()
    with caplog.at_level("WARNING", logger="hpcmpm"):
        simulate(parse_scene(unused, path="<unused>"), end_time=1e-3)
    assert not [r for r in caplog.records if "pass through" in r.getMessage()]


@pytest.mark.parametrize("t, centre0, velocity", [
    (0.0, (0.02, 0.5), (0.0, 0.0)),       # straddles the face x = 0
    (1.5, (0.52, 0.5), (1.0, 0.0)),       # travelled 1.5 periods: at 0.02 again
])
def test_collider_acts_through_its_periodic_images(t, centre0, velocity):
    """Domain [0, 1]^2 periodic along x (dx = 0.025; the block holds nodes -2 .. 42 along x,
    ghosts beyond both faces included): a sticky disk of radius 0.1 centred at x = 0.02 sets
    the rigid velocity on exactly the nodes within 0.1 of its centre or of its image one
    period away, on both sides of the face; one that has travelled out of the domain along
    the periodic axis acts where it has come round to. Before, only the nodes near the
    centre itself were (and none once it had left the domain)."""
    dx, n = 0.025, 40
    spec = collider_spec("sphere", {"center": centre0, "radius": 0.1}, velocity=velocity)
    collider = Collider(spec, 2, periods=[1.0, 0.0], domain_lo=[0.0, 0.0])
    origin = np.array([-2, 0])
    shape = (n + 5, n + 1)
    v = np.zeros(shape + (2,))
    v[..., 1] = 1.0
    collider.apply(v, origin, dx, np.zeros(2), t, 1e-12)
    i, j = np.meshgrid(np.arange(shape[0]) + origin[0], np.arange(shape[1]), indexing="ij")
    x, y = i * dx, j * dx
    near = np.minimum.reduce([np.hypot(x - 0.02 - k, y - 0.5) for k in (-1.0, 0.0, 1.0)])
    inside = near <= 0.1
    assert inside[x < 0.5].any() and inside[x > 0.5].any()      # both sides of the face
    np.testing.assert_allclose(v[inside], np.broadcast_to(velocity, v[inside].shape),
                               atol=1e-12)
    assert np.all(v[~inside] == [0.0, 1.0])


def test_periodic_collider_scene_errors():
    """On a periodic axis a collider reaching half the period would overlap its images, and
    a half-space with a normal along the axis (or turning) differs at the two faces: one
    line each, naming the key."""
    from hpcmpm.errors import SceneError
    from hpcmpm.scene import parse_scene

    base = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.05
end_time = 0.1
periodic = ["x"]
[[materials]]
name = "m"
type = "linear_elastic"
density = 1.0
E = 100.0
nu = 0.3
[[bodies]]
material = "m"
shape = "box"
lower = [0.2, 0.2]
upper = [0.4, 0.4]
[[colliders]]
"""
    cases = [('shape = "sphere"\ncenter = [0.5, 0.5]\nradius = 0.5',
              "colliders[0]: reaches 0.5 from its centre, half the period 1 of the periodic "
              "axis 'x' or more"),
             ('shape = "half_space"\npoint = [0.0, 0.1]\nnormal = [0.1, 1.0]',
              "colliders[0].normal: has a component along the periodic axis 'x'"),
             ('shape = "half_space"\npoint = [0.0, 0.1]\nnormal = [0.0, 1.0]\n'
              'angular_velocity = 0.1',
              "colliders[0].angular_velocity: a turning half-space")]
    for entry, expect in cases:
        with pytest.raises(SceneError) as err:
            parse_scene(base + entry, "s.toml")
        lines = str(err.value).splitlines()
        assert len(lines) == 1 and expect in lines[0], lines
    parse_scene(base + 'shape = "sphere"\ncenter = [0.02, 0.5]\nradius = 0.4', "s.toml")

"""Analytic colliders: rigid obstacles given by a signed distance, static or kinematic.

A collider moves with constant linear velocity ``v`` and spins with constant angular velocity
``omega`` about its centre: centre ``c(t) = c0 + v t``, orientation ``R(t) = exp(t [omega]x) R0``,
and the rigid velocity at ``x`` is ``v + omega x (x - c(t))``. Grid nodes inside
(``phi <= 0``) get their velocity relative to the obstacle projected (`contact.project`). The
collider is placed at the end of the step, ``t + dt``, so a moving obstacle pushes material out
of the space it is about to occupy (Stomakhin 2013 §8).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .contact import CONDITIONS, project

HALF_SPACE, SPHERE, BOX, CYLINDER = 0, 1, 2, 3
SHAPES = {"half_space": HALF_SPACE, "sphere": SPHERE, "box": BOX, "cylinder": CYLINDER}


def rotation_matrix(rotation_vector) -> np.ndarray:
    """Rodrigues: the rotation by |r| about r/|r| (3D)."""
    r = np.asarray(rotation_vector, dtype=np.float64)
    angle = np.linalg.norm(r)
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rotation_taking_z_to(axis) -> np.ndarray:
    """A rotation that maps e_z onto the unit vector ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, a))
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, a)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


@njit(cache=True, inline="always")
def signed_distance(shape, size, y0, y1, y2):
    """phi and outward normal of a shape centred at the origin of its body frame.

    size: half_space (unused; normal +z of the body frame), sphere (radius), box (half
    extents), cylinder (radius, half length; axis = body z)."""
    if shape == HALF_SPACE:
        return y2, 0.0, 0.0, 1.0
    if shape == SPHERE:
        r = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        if r == 0.0:
            return -size[0], 0.0, 0.0, 1.0
        return r - size[0], y0 / r, y1 / r, y2 / r
    if shape == BOX:
        q0, q1, q2 = abs(y0) - size[0], abs(y1) - size[1], abs(y2) - size[2]
        s0 = 1.0 if y0 >= 0 else -1.0
        s1 = 1.0 if y1 >= 0 else -1.0
        s2 = 1.0 if y2 >= 0 else -1.0
        m = max(q0, q1, q2)
        if m <= 0.0:  # inside: nearest face
            if m == q0:
                return m, s0, 0.0, 0.0
            if m == q1:
                return m, 0.0, s1, 0.0
            return m, 0.0, 0.0, s2
        a0, a1, a2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
        d = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        return d, s0 * a0 / d, s1 * a1 / d, s2 * a2 / d
    # cylinder: a 2D box in (radial, axial)
    rho = math.sqrt(y0 * y0 + y1 * y1)
    e0, e1 = (y0 / rho, y1 / rho) if rho > 0.0 else (1.0, 0.0)
    qr, qa = rho - size[0], abs(y2) - size[1]
    sa = 1.0 if y2 >= 0 else -1.0
    if max(qr, qa) <= 0.0:
        if qr >= qa:
            return qr, e0, e1, 0.0
        return qa, 0.0, 0.0, sa
    ar, aa = max(qr, 0.0), max(qa, 0.0)
    d = math.sqrt(ar * ar + aa * aa)
    return d, e0 * ar / d, e1 * ar / d, sa * aa / d


@njit(cache=True)
def apply_collider(velocity, mass, block_shape, origin, dx, domain_lo, shape, size, centre, R,
                   v_lin, omega, condition, friction):
    """Project the velocity of every node with mass inside the collider.

    velocity (N, dim) and mass (N,) are flattened block arrays of shape ``block_shape``;
    centre (3,), R (3, 3) body-to-world, v_lin, omega (3,) at the current time."""
    dim = velocity.shape[1]
    nz = block_shape[2] if dim == 3 else 1
    ny = block_shape[1]
    for n in range(velocity.shape[0]):
        if mass[n] <= 0.0:
            continue
        i = n // (ny * nz)
        j = (n // nz) % ny
        k = n % nz
        x0 = domain_lo[0] + (origin[0] + i) * dx - centre[0]
        x1 = domain_lo[1] + (origin[1] + j) * dx - centre[1]
        x2 = (domain_lo[2] + (origin[2] + k) * dx - centre[2]) if dim == 3 else 0.0
        # body frame: y = R^T x
        y0 = R[0, 0] * x0 + R[1, 0] * x1 + R[2, 0] * x2
        y1 = R[0, 1] * x0 + R[1, 1] * x1 + R[2, 1] * x2
        y2 = R[0, 2] * x0 + R[1, 2] * x1 + R[2, 2] * x2
        phi, m0, m1, m2 = signed_distance(shape, size, y0, y1, y2)
        if phi > 0.0:
            continue
        n0 = R[0, 0] * m0 + R[0, 1] * m1 + R[0, 2] * m2
        n1 = R[1, 0] * m0 + R[1, 1] * m1 + R[1, 2] * m2
        n2 = R[2, 0] * m0 + R[2, 1] * m1 + R[2, 2] * m2
        w0 = v_lin[0] + omega[1] * x2 - omega[2] * x1
        w1 = v_lin[1] + omega[2] * x0 - omega[0] * x2
        w2 = v_lin[2] + omega[0] * x1 - omega[1] * x0
        u2 = velocity[n, 2] - w2 if dim == 3 else 0.0
        r0, r1, r2 = project(velocity[n, 0] - w0, velocity[n, 1] - w1, u2, n0, n1, n2,
                             condition, friction)
        velocity[n, 0] = r0 + w0
        velocity[n, 1] = r1 + w1
        if dim == 3:
            velocity[n, 2] = r2 + w2


def _vec3(values, dim) -> np.ndarray:
    out = np.zeros(3)
    out[:dim] = np.asarray(values, dtype=np.float64)[:dim]
    return out


def _omega3(angular, dim) -> np.ndarray:
    """Angular velocity as a 3-vector; in 2D the scene gives a scalar about z."""
    if angular is None:
        return np.zeros(3)
    if dim == 2:
        value = float(np.ravel(np.asarray(angular, dtype=np.float64))[-1]) \
            if np.ndim(angular) else float(angular)
        return np.array([0.0, 0.0, value])
    return np.asarray(angular, dtype=np.float64).reshape(3)


class Collider:
    """One analytic obstacle from a scene's ``[[colliders]]`` entry."""

    name = "collider"

    def __init__(self, spec, dim: int):
        self.spec = spec
        self.dim = dim
        p = spec.params
        self.shape = SHAPES[spec.shape]
        self.condition = CONDITIONS[spec.condition]
        self.friction = float(spec.friction)
        self.velocity = _vec3(spec.velocity or (0.0,) * dim, dim)
        self.omega = _omega3(spec.angular_velocity, dim)
        self.start = float(spec.start)
        self.end = float(spec.end)
        self.size = np.zeros(3)
        R0 = np.eye(3)
        if self.shape == HALF_SPACE:
            self.centre0 = _vec3(p["point"], dim)
            R0 = rotation_taking_z_to(_vec3(p["normal"], dim))
        else:
            self.centre0 = _vec3(p["center"], dim)
        if self.shape == SPHERE:
            self.size[0] = float(p["radius"])
        elif self.shape == BOX:
            self.size[:dim] = np.asarray(p["half_extents"], dtype=np.float64)
            if dim == 2:
                self.size[2] = 1.0  # any positive extent: z is always 0 in 2D
            R0 = _initial_rotation(p.get("rotation"), dim)
        elif self.shape == CYLINDER:
            self.size[0] = float(p["radius"])
            self.size[1] = float(p["half_length"])
            R0 = rotation_taking_z_to(_vec3(p["axis"], dim))
        self.R0 = R0

    def position(self, t: float) -> np.ndarray:
        return self.centre0 + self.velocity * t

    def rotation(self, t: float) -> np.ndarray:
        return rotation_matrix(self.omega * t) @ self.R0

    def apply(self, velocity, origin, dx, domain_lo, t, dt, mass) -> None:
        t_end = t + dt
        if not (self.start <= t_end <= self.end):
            return
        dim = velocity.shape[-1]
        lo = np.zeros(3)
        lo[:dim] = domain_lo
        org = np.zeros(3, dtype=np.int64)
        org[:dim] = origin
        shape = np.ones(3, dtype=np.int64)
        shape[:dim] = velocity.shape[:-1]
        apply_collider(velocity.reshape(-1, dim), mass.reshape(-1), shape, org, dx, lo,
                       self.shape, self.size, self.position(t_end), self.rotation(t_end),
                       self.velocity, self.omega, self.condition, self.friction)


def _initial_rotation(rotation, dim) -> np.ndarray:
    if rotation is None:
        return np.eye(3)
    if dim == 2:
        return rotation_matrix([0.0, 0.0, float(np.ravel([rotation])[0])])
    return rotation_matrix(rotation)

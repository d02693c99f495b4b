"""Analytic colliders: rigid obstacles given by a signed distance, static or kinematic.

A collider moves with constant linear velocity ``v`` and spins with constant angular velocity
``omega`` about its centre: centre ``c(t) = c0 + v t``, orientation ``R(t) = exp(t [omega]x) R0``
(in 2D, a rotation by ``omega t`` about z), and the rigid velocity at ``x`` is
``v + omega x (x - c(t))``. It acts only while ``start <= t <= end``. Along periodic axes it
acts through its images one period either way, from its centre brought into the domain: it
acts across a face, and one that travels along the axis comes round again. Grid nodes inside
(``phi <= 0``) get their velocity relative to the obstacle projected (`contact.project`,
Stomakhin 2013 §8); so do off-grid particles (peridynamic bodies, 003 Alg. 2) whose position
after the step would be inside (`Collider.apply_to_particles`), by the same point rule
`project_relative`.

Shapes live in a body frame centred at the origin, ``y = R^T (x - c)``: half-space (the
obstacle is ``y_z <= 0``; R0 takes e_z to the scene's ``normal``, which points out of the
obstacle into the material), sphere (a disk in 2D), box (oriented; 2D angle or 3D rotation
vector), cylinder (3D, capped, axis = body z). 2D is the z = 0 plane of the 3D formulas.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numba import njit

from ._block import block3, mass3, omega3, vec3
from .contact import CONDITIONS, NO_BASIS, NO_COUNT, SEPARATE, constrain, project

HALF_SPACE, SPHERE, BOX, CYLINDER = 0, 1, 2, 3
SHAPES = {"half_space": HALF_SPACE, "sphere": SPHERE, "box": BOX, "cylinder": CYLINDER}


def rotation_matrix(rotation_vector) -> np.ndarray:
    """``exp([r]x)``: the rotation by ``|r|`` about ``r/|r|`` (Rodrigues' formula), 3x3."""
    r = np.asarray(rotation_vector, dtype=np.float64)
    angle = np.linalg.norm(r)
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rotation_taking_z_to(axis) -> np.ndarray:
    """A rotation that maps e_z onto the unit vector along ``axis``."""
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
    """phi and outward unit normal (phi, m0, m1, m2) at body-frame point y.

    Exact Euclidean signed distances (Quilez's box/cylinder formulas): outside, the distance
    to the nearest surface point; inside, minus the distance to the nearest face. size:
    sphere (radius,), box (half extents; inf along z in 2D), cylinder (radius, half length)."""
    if shape == HALF_SPACE:
        return y2, 0.0, 0.0, 1.0
    if shape == SPHERE:
        r = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        if r == 0.0:  # the centre: every direction is nearest, pick one
            return -size[0], 0.0, 0.0, 1.0
        return r - size[0], y0 / r, y1 / r, y2 / r
    if shape == BOX:
        q0, q1, q2 = abs(y0) - size[0], abs(y1) - size[1], abs(y2) - size[2]
        s0 = 1.0 if y0 >= 0 else -1.0
        s1 = 1.0 if y1 >= 0 else -1.0
        s2 = 1.0 if y2 >= 0 else -1.0
        m = max(q0, q1, q2)
        if m <= 0.0:  # inside: the nearest face
            if m == q0:
                return m, s0, 0.0, 0.0
            if m == q1:
                return m, 0.0, s1, 0.0
            return m, 0.0, 0.0, s2
        a0, a1, a2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
        d = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        return d, s0 * a0 / d, s1 * a1 / d, s2 * a2 / d
    # cylinder: a 2D box in (radial, axial) coordinates
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


@njit(cache=True, inline="always")
def world_level_set(shape, size, centre, R, x0, x1, x2):
    """phi and world-frame normal at offset ``x - c`` = (x0, x1, x2); R is body-to-world."""
    y0 = R[0, 0] * x0 + R[1, 0] * x1 + R[2, 0] * x2  # y = R^T x
    y1 = R[0, 1] * x0 + R[1, 1] * x1 + R[2, 1] * x2
    y2 = R[0, 2] * x0 + R[1, 2] * x1 + R[2, 2] * x2
    phi, m0, m1, m2 = signed_distance(shape, size, y0, y1, y2)
    n0 = R[0, 0] * m0 + R[0, 1] * m1 + R[0, 2] * m2
    n1 = R[1, 0] * m0 + R[1, 1] * m1 + R[1, 2] * m2
    n2 = R[2, 0] * m0 + R[2, 1] * m1 + R[2, 2] * m2
    return phi, n0, n1, n2


@njit(cache=True)
def level_set_at_points(x, shape, size, centre, R, phi, normal):
    """phi (n,) and outward normal (n, dim) of the collider at world points x (n, dim)."""
    dim = x.shape[1]
    for p in range(x.shape[0]):
        x2 = x[p, 2] - centre[2] if dim == 3 else 0.0
        f, n0, n1, n2 = world_level_set(shape, size, centre, R, x[p, 0] - centre[0],
                                        x[p, 1] - centre[1], x2)
        phi[p] = f
        normal[p, 0] = n0
        normal[p, 1] = n1
        if dim == 3:
            normal[p, 2] = n2


@njit(cache=True, inline="always")
def project_relative(shape, size, centre, R, v_lin, omega, condition, friction, x0, x1, x2,
                     u0, u1, u2):
    """(inside, u0, u1, u2): the velocity u at offset ``x - c`` = (x0, x1, x2) projected
    relative to the collider's rigid velocity ``v + omega x (x - c)`` when the point is
    inside (``phi <= 0``), else u unchanged. The one contact rule for grid nodes and for
    off-grid particles (hpcmpm/pd/contact.py). In 2D pass x2 = u2 = 0."""
    phi, n0, n1, n2 = world_level_set(shape, size, centre, R, x0, x1, x2)
    if phi > 0.0:
        return False, u0, u1, u2
    w0 = v_lin[0] + omega[1] * x2 - omega[2] * x1
    w1 = v_lin[1] + omega[2] * x0 - omega[0] * x2
    w2 = v_lin[2] + omega[0] * x1 - omega[1] * x0
    r0, r1, r2 = project(u0 - w0, u1 - w1, u2 - w2, n0, n1, n2, condition, friction)
    return True, r0 + w0, r1 + w1, r2 + w2


@njit(cache=True)
def project_collider(velocity, mass, use_mass, lo, hi, origin, dx, domain_lo, shape, size,
                     centre, R, v_lin, omega, condition, friction, record, basis, count):
    """Project the velocity of every node inside the collider (``phi <= 0``), relative to the
    collider's rigid velocity ``v + omega x (x - c)``; with ``record``, leave it and add the
    directions the collider fixes to ``basis``/``count`` instead (`contact.constrain`).

    velocity (n0, n1, n2, dim) and mass (n0, n1, n2) are 3D views of the block (n2 = 1 in 2D),
    visited over the block-index box ``lo <= j < hi`` that bounds the collider; origin,
    domain_lo (3,) padded; centre (3,), R (3, 3) body-to-world, v_lin, omega (3,)."""
    dim = velocity.shape[3]
    for i in range(lo[0], hi[0]):
        x0 = domain_lo[0] + (origin[0] + i) * dx - centre[0]
        for j in range(lo[1], hi[1]):
            x1 = domain_lo[1] + (origin[1] + j) * dx - centre[1]
            for k in range(lo[2], hi[2]):
                if use_mass and mass[i, j, k] <= 0.0:
                    continue
                x2 = (domain_lo[2] + (origin[2] + k) * dx - centre[2]) if dim == 3 else 0.0
                u2 = velocity[i, j, k, 2] if dim == 3 else 0.0
                if record:
                    phi, n0, n1, n2 = world_level_set(shape, size, centre, R, x0, x1, x2)
                    if phi > 0.0:
                        continue
                    w0 = v_lin[0] + omega[1] * x2 - omega[2] * x1
                    w1 = v_lin[1] + omega[2] * x0 - omega[0] * x2
                    w2 = v_lin[2] + omega[0] * x1 - omega[1] * x0
                    constrain(basis, count, i, j, k, velocity[i, j, k, 0] - w0,
                              velocity[i, j, k, 1] - w1, u2 - w2 if dim == 3 else 0.0,
                              n0, n1, n2, condition, dim)
                    continue
                inside, r0, r1, r2 = project_relative(
                    shape, size, centre, R, v_lin, omega, condition, friction, x0, x1, x2,
                    velocity[i, j, k, 0], velocity[i, j, k, 1], u2)
                if not inside:
                    continue
                velocity[i, j, k, 0] = r0
                velocity[i, j, k, 1] = r1
                if dim == 3:
                    velocity[i, j, k, 2] = r2


@njit(cache=True)
def project_collider_particles(x, v, dt, shape, size, centre, R, v_lin, omega, condition,
                               friction):
    """Off-grid particles (003 Alg. 2): a particle whose position after the step,
    ``x + dt v``, lies inside the collider (placed at the end of the step) gets its velocity
    projected there as a grid node's would be. x, v (n, dim); v in place. Returns the number
    of projections."""
    n, dim = x.shape
    hits = 0
    for p in range(n):
        u2 = v[p, 2] if dim == 3 else 0.0
        x2 = (x[p, 2] + dt * u2 - centre[2]) if dim == 3 else 0.0
        inside, r0, r1, r2 = project_relative(
            shape, size, centre, R, v_lin, omega, condition, friction,
            x[p, 0] + dt * v[p, 0] - centre[0], x[p, 1] + dt * v[p, 1] - centre[1], x2,
            v[p, 0], v[p, 1], u2)
        if not inside:
            continue
        v[p, 0] = r0
        v[p, 1] = r1
        if dim == 3:
            v[p, 2] = r2
        hits += 1
    return hits


class Collider:
    """One analytic obstacle from a scene's ``[[colliders]]`` entry (a `ColliderSpec`)."""

    name = "collider"

    def __init__(self, spec, dim: int, periods=None, domain_lo=None):
        self.spec = spec
        self.dim = dim
        # Periodic axes (period lengths, 0 elsewhere) of a domain starting at domain_lo: a
        # bounded collider also acts through its images one period away (`_centres`).
        self.periods = np.zeros(dim) if periods is None else \
            np.asarray(periods, dtype=np.float64).reshape(dim)
        self.period_lo = np.zeros(dim) if domain_lo is None else \
            np.asarray(domain_lo, dtype=np.float64).reshape(dim)
        p = spec.params
        self.shape = SHAPES[spec.shape]
        self.condition = CONDITIONS[spec.condition]
        self.friction = float(spec.friction)
        self.velocity = vec3(spec.velocity, dim)
        self.omega = omega3(spec.angular_velocity, dim)
        self.start = float(spec.start)
        self.end = float(spec.end)
        self.size = np.zeros(3)
        R0 = np.eye(3)
        if self.shape == HALF_SPACE:
            self.centre0 = vec3(p["point"], dim)
            R0 = rotation_taking_z_to(vec3(p["normal"], dim))
        else:
            self.centre0 = vec3(p["center"], dim)
        if self.shape == SPHERE:
            self.size[0] = float(p["radius"])
        elif self.shape == BOX:
            self.size[:dim] = np.asarray(p["half_extents"], dtype=np.float64)
            if dim == 2:
                # Unbounded along z: z = 0 in 2D, and a finite extent would make the z face
                # the "nearest face" deep inside a wide box.
                self.size[2] = np.inf
            R0 = _initial_rotation(p.get("rotation"), dim)
        elif self.shape == CYLINDER:
            self.size[0] = float(p["radius"])
            self.size[1] = float(p["half_length"])
            R0 = rotation_taking_z_to(vec3(p["axis"], dim))
        self.R0 = R0

    def position(self, t: float) -> np.ndarray:
        """Centre (the half-space's point) at time t, shape (dim,)."""
        return (self.centre0 + self.velocity * t)[: self.dim]

    def rotation(self, t: float) -> np.ndarray:
        """Body-to-world rotation ``R(t) = exp(t [omega]x) R0``, shape (3, 3); in 2D the
        upper-left 2x2 block is the in-plane rotation by ``angle0 + omega t`` (for a
        half-space R0 also turns body z onto the in-plane normal)."""
        return rotation_matrix(self.omega * t) @ self.R0

    def active(self, t: float) -> bool:
        return self.start <= t <= self.end

    def _centres(self, t: float) -> list[np.ndarray]:
        """Where the collider acts at time t, as 3-vectors: its centre, and along periodic
        axes the centre brought into the domain with its images one period either way (the
        scene check keeps a bounded collider within half a period of its centre, so the
        images do not overlap; a half-space there is the same at both faces: one is
        enough). A collider that travels along a periodic axis comes round again."""
        centre = self.position(t)
        if self.shape == HALF_SPACE or not self.periods.any():
            return [vec3(centre, self.dim)]
        p, lo = self.periods, self.period_lo
        inside = np.where(p > 0, lo + np.mod(centre - lo, np.where(p > 0, p, 1.0)), centre)
        steps = [(0, -1, 1) if p[a] > 0 else (0,) for a in range(self.dim)]
        return [vec3(inside + np.asarray(k) * p, self.dim) for k in itertools.product(*steps)]

    def level_set(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """phi (n,) and outward unit normal (n, dim) at world points x (n, dim), time t."""
        x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, self.dim)
        phi = np.empty(len(x))
        normal = np.zeros((len(x), self.dim))
        level_set_at_points(x, self.shape, self.size, vec3(self.position(t), self.dim),
                            self.rotation(t), phi, normal)
        return phi, normal

    def apply(self, velocity: np.ndarray, origin, dx: float, domain_lo, t: float, dt: float,
              mass: np.ndarray | None = None) -> None:
        """Project in place the velocity (block + (dim,)) of the nodes inside the collider.

        The collider is placed where it is at the END of the step, ``t + dt``: the grid
        velocity computed now moves the material from t to t + dt, so the nodes that must not
        move into the obstacle are those inside it at t + dt. Evaluating at t would let a
        moving collider sweep over material for one step before pushing it (Stomakhin 2013
        §8 uses the same choice). The active window is checked at the same time."""
        self._visit(velocity, origin, dx, domain_lo, t, dt, mass, False, NO_BASIS, NO_COUNT)

    @property
    def frictional(self) -> bool:
        """Whether the collider is separate with friction (see `Walls.frictional`)."""
        return self.condition == SEPARATE and self.friction > 0.0

    def constrain(self, velocity: np.ndarray, origin, dx: float, domain_lo, t: float,
                  dt: float, mass: np.ndarray, basis: np.ndarray, count: np.ndarray) -> None:
        """Add the directions the collider fixes at the trial ``velocity`` (placed at t + dt,
        as in `apply`) to ``basis`` (block3 + (3, 3)) and ``count`` (block3): the semi-implicit
        solve's constraint mask."""
        self._visit(velocity, origin, dx, domain_lo, t, dt, mass, True, basis, count)

    def _visit(self, velocity, origin, dx, domain_lo, t, dt, mass, record, basis, count):
        t_end = t + dt
        if not self.active(t_end):
            return
        dim = self.dim
        v3 = block3(velocity, dim)
        m3, use_mass = mass3(mass, dim)
        org = np.zeros(3, dtype=np.int64)
        org[:dim] = origin
        lo_x = vec3(domain_lo, dim)
        R = self.rotation(t_end)
        for centre in self._centres(t_end):
            lo, hi = self._node_box(centre, R, org, dx, lo_x, np.array(v3.shape[:3]))
            if np.any(hi <= lo):
                continue
            project_collider(v3, m3, use_mass, lo, hi, org, float(dx), lo_x, self.shape,
                             self.size, centre, R, self.velocity, self.omega, self.condition,
                             self.friction, record, basis, count)

    def apply_to_particles(self, x: np.ndarray, v: np.ndarray, t: float, dt: float) -> int:
        """Off-grid particles x, v (n, dim) (peridynamic bodies, 003 Alg. 2): the velocity of
        a particle about to move into the collider over [t, t + dt] is projected in place
        (`project_collider_particles`); the collider is placed at t + dt as for the grid.
        Returns the number of projections."""
        t_end = t + dt
        if not self.active(t_end) or len(x) == 0:
            return 0
        R = self.rotation(t_end)
        return sum(project_collider_particles(
            x, v, float(dt), self.shape, self.size, centre, R, self.velocity, self.omega,
            self.condition, self.friction) for centre in self._centres(t_end))

    def _node_box(self, centre, R, origin, dx, domain_lo, shape):
        """Block-index box of the nodes that can be inside: the collider's world bounding
        box, widened by a node against round-off; the whole block for a half-space."""
        lo = np.zeros(3, dtype=np.int64)
        hi = shape.astype(np.int64)
        if self.shape == HALF_SPACE:
            return lo, hi
        d = self.dim
        if self.shape == SPHERE:
            extent = np.full(d, self.size[0])
        elif self.shape == BOX:
            extent = np.abs(R[:d, :d]) @ self.size[:d]
        else:
            axis = R[:, 2]
            extent = np.abs(axis) * self.size[1] + self.size[0] * np.sqrt(
                np.maximum(0.0, 1.0 - axis * axis))
        # Clipped to the block while still floats: a collider far larger than the domain
        # (half-extents of 9e18 cells) has node indices beyond int64, whose cast gave
        # INT64_MIN, an empty box, and a collider that acted on no node.
        block_lo = origin[:d] - 1.0
        block_hi = origin[:d] + shape[:d] + 1.0
        first = np.clip(np.floor((centre[:d] - extent - domain_lo[:d]) / dx), block_lo, block_hi)
        last = np.clip(np.ceil((centre[:d] + extent - domain_lo[:d]) / dx), block_lo, block_hi)
        lo[:d] = np.clip(first.astype(np.int64) - 1 - origin[:d], 0, shape[:d])
        hi[:d] = np.clip(last.astype(np.int64) + 2 - origin[:d], 0, shape[:d])
        return lo, hi


def _initial_rotation(rotation, dim) -> np.ndarray:
    """R0 of a box: 2D angle (radians) about z, or 3D rotation vector."""
    if rotation is None:
        return np.eye(3)
    if dim == 2:
        return rotation_matrix([0.0, 0.0, float(np.ravel([rotation])[0])])
    return rotation_matrix(rotation)

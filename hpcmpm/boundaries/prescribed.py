"""Particle sets with prescribed rigid motion: hold the ends of a sponge and twist one
(000 Fig. 5.1).

The Dirichlet data is carried by particles (the per-particle int field ``prescribed``: the set
index, or -1) but imposed on the grid: every node in the B-spline support of a marked particle
gets the set's rigid velocity ``v + omega x (x_i - c(t))``, ``c(t) = center + v t``.

Why on the nodes: G2P gives a particle ``v_p = sum_i w_ip v_i`` and ``grad v_p =
sum_i v_i (grad w_ip)^T``. B-splines are a partition of unity (``sum_i w_ip = 1``,
``sum_i grad w_ip = 0``) and reproduce linear functions (``sum_i w_ip x_i = x_p``,
``sum_i x_i (grad w_ip)^T = I``; 000 §3.2). A rigid velocity is linear in x, so a particle
whose whole support is tagged gets exactly ``v + omega x (x_p - c)`` and exactly
``grad v = [omega]x``: its position, and through ``F <- (I + dt grad v) F`` its deformation
gradient, follow the rigid motion, and the free particles next to the set feel a clamped
boundary through the shared nodes. Overwriting particle velocities after G2P instead would
leave the nodes free: neighbours would see a soft clamp, and the set's own ``grad v`` (hence F
and stress) would come from the unconstrained grid.

The node marks (`PrescribedSet.scatter` / `.apply`, used by `Simulation`): one float count
field per set, scattered like mass, so `Domain.sum_ghosts_to_owners` tells an owner that a node
is clamped even when the marked particles live on another rank (an int tag has no such sum).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..kernels.shape import stencil_base
from ._block import block3, omega3, vec3


@njit(cache=True, inline="always")
def rigid_velocity(v_lin, omega, x0, x1, x2):
    """``v + omega x r`` at offset r = (x0, x1, x2) from the centre."""
    return (v_lin[0] + omega[1] * x2 - omega[2] * x1,
            v_lin[1] + omega[2] * x0 - omega[0] * x2,
            v_lin[2] + omega[0] * x1 - omega[1] * x0)


@njit(cache=True, inline="always")
def support_box(x, p, order, inv_dx, domain_lo, origin, n0, n1, n2):
    """Block-index ranges [a0, b0) x [a1, b1) x [a2, b2) of particle p's B-spline support
    (ARCHITECTURE.md), clipped to the block (n0, n1, n2); one node along z in 2D."""
    s = order + 1
    c0 = stencil_base((x[p, 0] - domain_lo[0]) * inv_dx, order) - origin[0]
    c1 = stencil_base((x[p, 1] - domain_lo[1]) * inv_dx, order) - origin[1]
    c2, s2 = 0, 1
    if x.shape[1] == 3:
        c2 = stencil_base((x[p, 2] - domain_lo[2]) * inv_dx, order) - origin[2]
        s2 = s
    return (max(c0, 0), min(c0 + s, n0), max(c1, 0), min(c1 + s, n1), max(c2, 0),
            min(c2 + s2, n2))


@njit(cache=True)
def scatter_marks(x, prescribed, set_index, order, dx, domain_lo, origin, marks):
    """Add 1 to ``marks`` (n0, n1, n2) at every support node of each particle whose
    ``prescribed`` equals ``set_index``; origin, domain_lo (3,) padded."""
    inv_dx = 1.0 / dx
    n0, n1, n2 = marks.shape
    for p in range(x.shape[0]):
        if prescribed[p] != set_index:
            continue
        a0, b0, a1, b1, a2, b2 = support_box(x, p, order, inv_dx, domain_lo, origin, n0, n1, n2)
        for i in range(a0, b0):
            for j in range(a1, b1):
                for k in range(a2, b2):
                    marks[i, j, k] += 1.0


@njit(cache=True)
def _nearest(offset, period):
    """``offset`` less the whole periods that bring it nearest to 0 (``period`` 0: as is)."""
    if period > 0.0:
        return offset - period * round(offset / period)
    return offset


@njit(cache=True)
def impose_rigid_velocity(velocity, marks, origin, dx, domain_lo, centre, v_lin, omega,
                          period):
    """Nodes with ``marks > 0`` get ``v + omega x (x - centre)``; velocity (n0, n1, n2, dim),
    marks (n0, n1, n2); origin, domain_lo, centre, v_lin, omega (3,). Along a periodic axis
    (``period`` (3,) lengths, 0 elsewhere) ``x - centre`` is the nearest image's: a set's
    particles that wrapped across a face turn about the centre they left."""
    dim = velocity.shape[3]
    n0, n1, n2 = marks.shape
    for i in range(n0):
        x0 = _nearest(domain_lo[0] + (origin[0] + i) * dx - centre[0], period[0])
        for j in range(n1):
            x1 = _nearest(domain_lo[1] + (origin[1] + j) * dx - centre[1], period[1])
            for k in range(n2):
                if marks[i, j, k] <= 0.0:
                    continue
                x2 = _nearest(domain_lo[2] + (origin[2] + k) * dx - centre[2], period[2]) \
                    if dim == 3 else 0.0
                w0, w1, w2 = rigid_velocity(v_lin, omega, x0, x1, x2)
                velocity[i, j, k, 0] = w0
                velocity[i, j, k, 1] = w1
                if dim == 3:
                    velocity[i, j, k, 2] = w2


class PrescribedSet:
    """The particles initially inside ``region`` move rigidly: centre ``c(t) = center + v t``
    (``center`` defaults to the region's middle), angular velocity ``omega`` about it."""

    def __init__(self, spec, index: int, dim: int, periods=None):
        self.spec = spec
        self.index = index
        self.dim = dim
        # Period lengths of the periodic axes (0 elsewhere; `impose_rigid_velocity`).
        self.periods = vec3(np.zeros(dim) if periods is None else periods, dim)
        self.lower = np.asarray(spec.region["lower"], dtype=np.float64)
        self.upper = np.asarray(spec.region["upper"], dtype=np.float64)
        centre = spec.center if spec.center is not None else (self.lower + self.upper) / 2
        self.centre0 = vec3(centre, dim)
        self.velocity = vec3(spec.velocity, dim)
        self.omega = omega3(spec.angular_velocity, dim)
        self.mark_field = f"prescribed_{index}"  # the float count grid field (Simulation)

    def select(self, x0: np.ndarray) -> np.ndarray:
        """Boolean mask (n,) of the particles at x0 (n, dim) inside the region (closed)."""
        return np.all((x0 >= self.lower) & (x0 <= self.upper), axis=1)

    def centre(self, t: float) -> np.ndarray:
        """Centre at time t, padded to 3 components."""
        return self.centre0 + self.velocity * t

    def scatter(self, particles, grid, order: int, start: int = 0, stop: int | None = None
                ) -> None:
        """Count, per node, this set's particles (of the rows [start, stop)) whose support
        holds it (after P2G)."""
        org = np.zeros(3, dtype=np.int64)
        org[: self.dim] = grid.origin
        rows = slice(start, particles.n if stop is None else stop)
        scatter_marks(particles["x"][rows], particles["prescribed"][rows], self.index, order,
                      grid.dx, vec3(grid.domain_lo, self.dim), org,
                      block3(grid[self.mark_field], self.dim))

    def apply(self, velocity, origin, dx, domain_lo, t, dt, grid) -> None:
        """Impose the rigid velocity on the nodes this set marked, centred at ``c(t)``, ``t``
        the START of the step: the node velocity moves the particles from where they are at
        t, so the rigid field must be centred where the set is at t (centring at t + dt would
        add a spurious ``-dt omega x v`` every step). Called after walls and colliders."""
        org = np.zeros(3, dtype=np.int64)
        org[: self.dim] = origin
        impose_rigid_velocity(block3(velocity, self.dim), block3(grid[self.mark_field], self.dim),
                              org, float(dx), vec3(domain_lo, self.dim), self.centre(t),
                              self.velocity, self.omega, self.periods)

    def constrain(self, velocity, origin, dx, domain_lo, t, dt, grid, basis, count) -> None:
        """Every node this set marked is fixed in all directions (the semi-implicit solve's
        constraint mask; `apply` gives the values)."""
        marked = block3(grid[self.mark_field], self.dim) > 0.0
        count[marked] = self.dim
        basis[marked] = np.eye(3)


def mark_prescribed_particles(scene, particles) -> None:
    """Set the per-particle ``prescribed`` index from the sets' regions (first match wins)."""
    x = particles["x"]
    tags = particles["prescribed"]
    tags[:] = -1
    for index, spec in enumerate(scene.prescribed):
        chosen = PrescribedSet(spec, index, scene.dim).select(x) & (tags < 0)
        tags[chosen] = index

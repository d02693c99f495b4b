"""Particle sets with prescribed rigid motion (hold the ends of a sponge and twist one,
000 Fig. 5.1).

The Dirichlet data is carried by particles but imposed on the grid: every node in the B-spline
support of a marked particle gets the set's rigid velocity ``v + omega x (x - c(t))``. G2P then
gives each marked particle exactly that rigid velocity and velocity gradient (partition of unity
and linear completeness of B-splines reproduce a linear field exactly), so its F follows the
rigid motion, and neighbouring free particles feel a clamped boundary. Overwriting particle
velocities after G2P instead would leave the nodes free and the clamp soft.

The node marks are counts scattered like mass and summed across ranks, so an owner knows that
a node is clamped even when the marked particles live on another rank.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..kernels.shape import stencil_base


@njit(cache=True)
def scatter_marks(x, prescribed, set_index, order, dx, domain_lo, origin, block_shape, marks):
    """Add 1 to ``marks`` (flattened block) at every support node of each particle whose
    ``prescribed`` equals ``set_index``."""
    dim = x.shape[1]
    inv_dx = 1.0 / dx
    s = order + 1
    nz = block_shape[2] if dim == 3 else 1
    ny = block_shape[1]
    for p in range(x.shape[0]):
        if prescribed[p] != set_index:
            continue
        b0 = stencil_base((x[p, 0] - domain_lo[0]) * inv_dx, order) - origin[0]
        b1 = stencil_base((x[p, 1] - domain_lo[1]) * inv_dx, order) - origin[1]
        b2 = 0
        s2 = 1
        if dim == 3:
            b2 = stencil_base((x[p, 2] - domain_lo[2]) * inv_dx, order) - origin[2]
            s2 = s
        for i in range(s):
            for j in range(s):
                for k in range(s2):
                    marks[((b0 + i) * ny + (b1 + j)) * nz + (b2 + k)] += 1.0


@njit(cache=True)
def impose_rigid_velocity(velocity, marks, block_shape, origin, dx, domain_lo, centre, v_lin,
                          omega):
    """Nodes with a mark get ``v + omega x (x - centre)``; velocity (N, dim) flattened."""
    dim = velocity.shape[1]
    nz = block_shape[2] if dim == 3 else 1
    ny = block_shape[1]
    for n in range(velocity.shape[0]):
        if marks[n] <= 0.0:
            continue
        i = n // (ny * nz)
        j = (n // nz) % ny
        k = n % nz
        x0 = domain_lo[0] + (origin[0] + i) * dx - centre[0]
        x1 = domain_lo[1] + (origin[1] + j) * dx - centre[1]
        x2 = (domain_lo[2] + (origin[2] + k) * dx - centre[2]) if dim == 3 else 0.0
        velocity[n, 0] = v_lin[0] + omega[1] * x2 - omega[2] * x1
        velocity[n, 1] = v_lin[1] + omega[2] * x0 - omega[0] * x2
        if dim == 3:
            velocity[n, 2] = v_lin[2] + omega[0] * x1 - omega[1] * x0


class PrescribedSet:
    """A set of particles (those initially inside ``region``) moving rigidly."""

    def __init__(self, spec, index: int, dim: int):
        from .colliders import _omega3, _vec3

        self.spec = spec
        self.index = index
        self.dim = dim
        self.lower = np.asarray(spec.region["lower"], dtype=np.float64)
        self.upper = np.asarray(spec.region["upper"], dtype=np.float64)
        centre = spec.center if spec.center is not None else (self.lower + self.upper) / 2
        self.centre0 = _vec3(centre, dim)
        self.velocity = _vec3(spec.velocity or (0.0,) * dim, dim)
        self.omega = _omega3(spec.angular_velocity, dim)
        self.mark_field = f"prescribed_{index}"

    def select(self, x: np.ndarray) -> np.ndarray:
        return np.all((x >= self.lower) & (x <= self.upper), axis=1)

    def centre(self, t: float) -> np.ndarray:
        return self.centre0 + self.velocity * t

    def scatter(self, particles, grid, order: int) -> None:
        scatter_marks(particles["x"], particles["prescribed"], self.index, order, grid.dx,
                      grid.domain_lo, grid.origin, _shape3(grid), grid[self.mark_field].reshape(-1))

    def apply(self, velocity, origin, dx, domain_lo, t, dt, grid) -> None:
        dim = velocity.shape[-1]
        lo = np.zeros(3)
        lo[:dim] = domain_lo
        org = np.zeros(3, dtype=np.int64)
        org[:dim] = origin
        impose_rigid_velocity(velocity.reshape(-1, dim), grid[self.mark_field].reshape(-1),
                              _shape3(grid), org, dx, lo, self.centre(t + dt), self.velocity,
                              self.omega)


def _shape3(grid) -> np.ndarray:
    shape = np.ones(3, dtype=np.int64)
    shape[: grid.dim] = grid.shape
    return shape


def mark_prescribed_particles(scene, particles) -> None:
    """Set the per-particle ``prescribed`` index from the sets' regions (first match wins)."""
    x = particles["x"]
    tags = particles["prescribed"]
    tags[:] = -1
    for index, spec in enumerate(scene.prescribed):
        chosen = PrescribedSet(spec, index, scene.dim).select(x) & (tags < 0)
        tags[chosen] = index

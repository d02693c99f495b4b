"""The explicit MPM step (000 §3.3, Fig. 3.1; Hu 2018 for MLS) and its CFL time step."""

from __future__ import annotations

import math
from typing import ClassVar


class ExplicitIntegrator:
    """Symplectic Euler on the grid: stress at the state of the last step, forces to the grid,
    v_i^{n+1} = v_i^n + dt f_i / m_i, back to the particles, then the materials' state update."""

    name: ClassVar[str] = "explicit"
    needs_velocity_gradient: ClassVar[bool] = False

    def __init__(self, sim):
        self.sim = sim

    @staticmethod
    def grid_step(sim, dt: float) -> None:
        """The step's grid part (`Simulation.step` runs the rest): stress and P2G, the grid
        update, G2P and the state update."""
        sim.fit_grid()
        sim.scatter_stress(dt)  # per chunk: Kirchhoff stress, then P2G of m, mv, dt f (eq. 3.1)
        sim.scatter_forces(dt)  # extensions' particle forces (integral-based MPM, 003 eq. 5.2)
        sim.sum_ghosts()
        sim.update_grid(dt)  # v_i = (p_i + dt f_i)/m_i + dt g, then boundaries
        sim.fill_ghosts()
        sim.remember_volumes()  # volume_averaging: x^n, J^n for the average below
        sim.gather(dt)  # v, C, x <- x + dt v; F <- (I + dt L) F, or L stored (eq. 3.7)
        sim.update_states(dt)  # plastic return maps, rate-dependent state over this dt
        sim.average_volumes()  # volume_averaging: the step's change of J, grid-averaged

    @staticmethod
    def scratch_bytes_per_particle(dim: int) -> int:
        """No per-particle arrays beyond the particle fields."""
        return 0

    def stable_dt(self, sim, speed: float) -> float:
        """``cfl dx / (c_max + |v|_max)`` (the wave-speed CFL bound), and no more than any
        material's own explicit limit (e.g. viscous: rho dx^2 / (2 d mu_N))."""
        speed += sim.max_wave_speed()
        dt = sim.scene.cfl * sim.dx / speed if speed > 0 else math.inf
        return min(dt, explicit_limits(sim, sim.materials))


def explicit_limits(sim, materials) -> float:
    """The smallest explicit time step bound of ``materials`` (`Material.dt_limit`: viscous,
    peridynamic, ...) and of the step extensions (e.g. the PD bound of SPB-MPM's bonds);
    inf when none binds."""
    dt = math.inf
    for material in materials:
        dt = min(dt, material.dt_limit(sim.dx))
    for extension in sim.extensions:
        if hasattr(extension, "dt_limit"):
            dt = min(dt, extension.dt_limit(sim))
    return dt

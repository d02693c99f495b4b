"""MLS-MPM in Taichi: the peer that hpcmpm's benchmarks run against.

Written for this benchmark after the structure of Taichi's public examples mpm88.py (2D, the
J-based weakly compressible fluid), mpm99.py (the fixed corotated stress) and mpm3d.py (the
dimension-generic loops and the wall condition): one kernel per substep with three loops
(clear grid + P2G, grid update, G2P), quadratic B-splines, MLS-MPM (Hu et al. 2018), float64,
and the walls of the examples (``bound`` = 3 nodes per side, velocity component into a wall
zeroed, "separate" condition). Two changes from the examples, both so that the two codes do the
same work from the same state: positions, velocities and the particle volume/mass come from the
caller instead of ``ti.random()``, and the fixed corotated rotation is ``ti.polar_decompose``
(mpm99 takes it from ``ti.svd``; in 3D Taichi's polar decomposition is that SVD).

Use: ``init(threads)`` once per process, then ``MLSMPM(...)``; ``substep()`` advances one step
and ``sync()`` waits for it. ``python scripts/peer/mls_mpm.py`` runs mpm88's scene for a few
hundred steps and prints the time per step.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

FLUID, COROTATED = "weakly_compressible", "fixed_corotated"


def init(threads: int = 1) -> None:
    """Taichi on the CPU backend, float64, ``threads`` worker threads."""
    ti.init(arch=ti.cpu, default_fp=ti.f64, cpu_max_num_threads=threads, log_level=ti.WARN)


def sync() -> None:
    ti.sync()


@ti.data_oriented
class MLSMPM:
    """Explicit MLS-MPM on a dense ``n_grid**dim`` grid over the unit box."""

    def __init__(self, dim: int, n_grid: int, dt: float, x0: np.ndarray, v0: np.ndarray,
                 p_vol: float, p_rho: float, material: str, E: float, nu: float = 0.0,
                 gravity: float = 9.8, bound: int = 3):
        n = len(x0)
        self.dim, self.n_grid, self.dt, self.bound = dim, n_grid, dt, bound
        self.dx = 1.0 / n_grid
        self.inv_dx = float(n_grid)
        self.p_vol, self.p_mass = p_vol, p_vol * p_rho
        self.gravity = gravity
        self.fluid = material == FLUID
        self.E = E
        self.mu = E / (2 * (1 + nu))
        self.lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        self.x = ti.Vector.field(dim, float, n)
        self.v = ti.Vector.field(dim, float, n)
        self.C = ti.Matrix.field(dim, dim, float, n)
        self.J = ti.field(float, n)  # the fluid's state
        self.F = ti.Matrix.field(dim, dim, float, n if not self.fluid else 1)
        self.grid_v = ti.Vector.field(dim, float, (n_grid,) * dim)
        self.grid_m = ti.field(float, (n_grid,) * dim)
        self.x.from_numpy(np.ascontiguousarray(x0, dtype=np.float64))
        self.v.from_numpy(np.ascontiguousarray(v0, dtype=np.float64))
        self.reset_state()

    @ti.kernel
    def reset_state(self):
        for p in self.x:
            self.C[p] = ti.Matrix.zero(float, self.dim, self.dim)
            self.J[p] = 1.0
            if ti.static(not self.fluid):
                self.F[p] = ti.Matrix.identity(float, self.dim)

    @ti.func
    def kirchhoff(self, p):
        """tau = E (J - 1) I (mpm88), or 2 mu (F - R) F^T + lam J (J - 1) I (mpm99)."""
        tau = ti.Matrix.zero(float, self.dim, self.dim)
        if ti.static(self.fluid):
            tau = self.E * (self.J[p] - 1) * ti.Matrix.identity(float, self.dim)
        else:
            F = self.F[p]
            R, _ = ti.polar_decompose(F)
            J = F.determinant()
            tau = 2 * self.mu * (F - R) @ F.transpose() \
                + ti.Matrix.identity(float, self.dim) * self.lam * J * (J - 1)
        return tau

    @ti.kernel
    def substep(self):
        dim, dx, inv_dx, dt = ti.static(self.dim, self.dx, self.inv_dx, self.dt)
        for I in ti.grouped(self.grid_m):
            self.grid_v[I] = ti.Vector.zero(float, dim)
            self.grid_m[I] = 0
        for p in self.x:  # P2G
            Xp = self.x[p] * inv_dx
            base = int(Xp - 0.5)
            fx = Xp - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
            stress = -dt * self.p_vol * 4 * inv_dx * inv_dx * self.kirchhoff(p)
            affine = stress + self.p_mass * self.C[p]
            for offset in ti.static(ti.grouped(ti.ndrange(*((3,) * dim)))):
                dpos = (offset - fx) * dx
                weight = 1.0
                for d in ti.static(range(dim)):
                    weight *= w[offset[d]][d]
                self.grid_v[base + offset] += weight * (self.p_mass * self.v[p] + affine @ dpos)
                self.grid_m[base + offset] += weight * self.p_mass
        for I in ti.grouped(self.grid_m):  # grid update and walls
            if self.grid_m[I] > 0:
                self.grid_v[I] /= self.grid_m[I]
            self.grid_v[I][1] -= dt * self.gravity
            cond = (I < self.bound) & (self.grid_v[I] < 0) | \
                   (I > self.n_grid - self.bound) & (self.grid_v[I] > 0)
            self.grid_v[I] = ti.select(cond, 0, self.grid_v[I])
        for p in self.x:  # G2P
            Xp = self.x[p] * inv_dx
            base = int(Xp - 0.5)
            fx = Xp - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
            new_v = ti.Vector.zero(float, dim)
            new_C = ti.Matrix.zero(float, dim, dim)
            for offset in ti.static(ti.grouped(ti.ndrange(*((3,) * dim)))):
                dpos = (offset - fx) * dx
                weight = 1.0
                for d in ti.static(range(dim)):
                    weight *= w[offset[d]][d]
                g_v = self.grid_v[base + offset]
                new_v += weight * g_v
                new_C += 4 * weight * g_v.outer_product(dpos) * inv_dx * inv_dx
            self.v[p] = new_v
            self.x[p] += dt * new_v
            self.C[p] = new_C
            if ti.static(self.fluid):
                self.J[p] *= 1 + dt * new_C.trace()
            else:
                self.F[p] = (ti.Matrix.identity(float, dim) + dt * new_C) @ self.F[p]

    def positions(self) -> np.ndarray:
        return self.x.to_numpy()

    def velocities(self) -> np.ndarray:
        return self.v.to_numpy()


if __name__ == "__main__":
    import time

    init(1)
    rng = np.random.default_rng(0)
    n_grid = 128
    x0 = rng.random((8192, 2)) * 0.4 + 0.2
    v0 = np.tile([0.0, -1.0], (8192, 1))
    sim = MLSMPM(2, n_grid, 2e-4, x0, v0, (0.5 / n_grid) ** 2, 1.0, FLUID, 400.0)
    sim.substep()
    sync()
    start = time.perf_counter()
    for _ in range(500):
        sim.substep()
    sync()
    print(f"mpm88 scene, Taichi CPU f64 1 thread: "
          f"{1e3 * (time.perf_counter() - start) / 500:.3f} ms/step")

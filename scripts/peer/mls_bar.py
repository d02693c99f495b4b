"""The peer's MLS-MPM (scripts/peer/mls_mpm.py) on an hpcmpm scene's grid, for the axial bar of
the error study (scripts/study_error.py, inputs/bar_2d.toml).

The P2G / grid / G2P loops are mls_mpm.py's (quadratic B-splines, MLS-MPM of Hu et al. 2018,
float64, one kernel per substep), with the changes the bar needs so that both codes solve the
same discrete problem from the same particles:

- the grid is hpcmpm's: nodes ``i dx`` from the scene's ``domain_lo`` (not the unit box), with a
  margin of two nodes for the stencil; the stencil base is ``floor(xi - 1/2)`` as in hpcmpm
  (mls_mpm.py's ``int(xi - 1/2)`` truncates towards zero, the floor only for ``xi >= 1/2``,
  and the bar's first particles sit at ``xi = 1/4``);
- the walls are hpcmpm's (``hpcmpm/boundaries/walls.py``): each face of the domain acts on the
  nodes on or beyond it (``i <= 0``, ``i >= n_cells``), sticky (v = 0), slip (normal component
  removed) or separate (normal component removed when moving out), no friction;
- the material is hpcmpm's ``linear_elastic`` (small-strain Hooke on ``eps = sym(F) - I``,
  ``tau = P F^T`` with ``P = 2 mu eps + lam tr(eps) I``); the peer's own fixed corotated stress
  (mpm99) is kept as an option;
- dt is a kernel argument, chosen by hpcmpm's rule (``hpcmpm/runner.py``): ``cfl dx / (c + max
  |v_p|)`` with ``c = sqrt((lam + 2 mu) / rho)``, clipped so that steps land on the output
  times ``k * frame_every`` and on the end time; no gravity (the bar has none).

The step kernel also returns the centre-of-mass x-velocity and the largest particle speed after
the step (the next step's CFL): the observable of the study, which the hpcmpm run records after
every step too.

Use: ``mls_mpm.init(1)`` once per process, ``bar = MLSBar(...)``, then ``bar.reset()`` and
``t, vcm = bar.run(end_time, frame_every)`` as often as wanted (the first run compiles).
"""

import math  # no `from __future__ import annotations`: Taichi reads the kernels' annotations

import numpy as np
import taichi as ti

LINEAR, COROTATED = "linear_elastic", "fixed_corotated"
STICKY, SLIP, SEPARATE = 0, 1, 2
CONDITIONS = {"sticky": STICKY, "slip": SLIP, "separate": SEPARATE}
PAD = 2  # grid nodes kept beyond each face for the quadratic stencil


@ti.data_oriented
class MLSBar:
    """Explicit 2D MLS-MPM with quadratic B-splines on the box ``domain_lo .. domain_hi``."""

    def __init__(self, domain_lo, domain_hi, dx: float, x0: np.ndarray, v0: np.ndarray,
                 p_mass: float, p_vol: float, rho: float, E: float, nu: float,
                 walls=("sticky", "slip", "slip", "slip"), cfl: float = 0.4,
                 material: str = LINEAR):
        if material not in (LINEAR, COROTATED):
            raise ValueError(f"material {material!r}: {LINEAR} or {COROTATED}")
        dim = 2
        self.dim, self.dx, self.inv_dx = dim, float(dx), 1.0 / float(dx)
        self.lo = tuple(float(a) for a in domain_lo)
        self.n_cells = tuple(int(round((float(hi) - float(lo)) / dx))
                             for lo, hi in zip(domain_lo, domain_hi))
        self.walls = tuple(CONDITIONS[w] for w in walls)
        if len(self.walls) != 2 * dim:
            raise ValueError(f"walls: {2 * dim} faces (x-, x+, y-, y+), got {len(walls)}")
        self.p_mass, self.p_vol = float(p_mass), float(p_vol)
        self.linear = material == LINEAR
        self.mu = E / (2 * (1 + nu))
        self.lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        self.wave_speed = math.sqrt((self.lam + 2 * self.mu) / rho)
        self.cfl = float(cfl)
        self.x0 = np.ascontiguousarray(x0, dtype=np.float64)
        self.v0 = np.ascontiguousarray(v0, dtype=np.float64)
        n = len(self.x0)
        self.x = ti.Vector.field(dim, float, n)
        self.v = ti.Vector.field(dim, float, n)
        self.C = ti.Matrix.field(dim, dim, float, n)
        self.F = ti.Matrix.field(dim, dim, float, n)
        shape = tuple(c + 1 + 2 * PAD for c in self.n_cells)
        self.grid_v = ti.Vector.field(dim, float, shape, offset=(-PAD,) * dim)
        self.grid_m = ti.field(float, shape, offset=(-PAD,) * dim)
        self.steps = 0

    def reset(self) -> None:
        """Back to the initial particles: x0, v0, C = 0, F = I."""
        self.x.from_numpy(self.x0)
        self.v.from_numpy(self.v0)
        self.reset_state()

    @ti.kernel
    def reset_state(self):
        for p in self.x:
            self.C[p] = ti.Matrix.zero(float, self.dim, self.dim)
            self.F[p] = ti.Matrix.identity(float, self.dim)

    @ti.func
    def kirchhoff(self, p):
        """hpcmpm's linear_elastic: tau = (2 mu eps + lam tr(eps) I) F^T, eps = sym(F) - I;
        or mpm99's fixed corotated 2 mu (F - R) F^T + lam J (J - 1) I."""
        F = self.F[p]
        Id = ti.Matrix.identity(float, self.dim)
        tau = ti.Matrix.zero(float, self.dim, self.dim)
        if ti.static(self.linear):
            eps = 0.5 * (F + F.transpose()) - Id
            tau = (2 * self.mu * eps + self.lam * eps.trace() * Id) @ F.transpose()
        else:
            R, _ = ti.polar_decompose(F)
            J = F.determinant()
            tau = 2 * self.mu * (F - R) @ F.transpose() + Id * self.lam * J * (J - 1)
        return tau

    @ti.kernel
    def substep(self, dt: ti.f64) -> ti.types.vector(2, ti.f64):
        """One step; returns what `observe` returns, after the step (summed in G2P, which
        saves a second kernel launch per step: at the bar's sizes a launch costs about as
        much as the step's arithmetic)."""
        dim, dx, inv_dx = ti.static(self.dim, self.dx, self.inv_dx)
        lo = ti.Vector(self.lo, dt=float)
        vx = 0.0
        vmax2 = 0.0
        for I in ti.grouped(self.grid_m):
            self.grid_v[I] = ti.Vector.zero(float, dim)
            self.grid_m[I] = 0
        for p in self.x:  # P2G
            Xp = (self.x[p] - lo) * inv_dx
            base = ti.cast(ti.floor(Xp - 0.5), ti.i32)
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
        for I in ti.grouped(self.grid_m):  # grid update and hpcmpm's walls
            v = ti.Vector.zero(float, dim)
            if self.grid_m[I] > 0:
                v = self.grid_v[I] / self.grid_m[I]
                for face in ti.static(range(2 * dim)):
                    axis, cond = ti.static(face // 2, self.walls[face])
                    sign = ti.static(-1.0 if face % 2 else 1.0)  # the face's inward normal
                    on = 0
                    if ti.static(face % 2):
                        on = I[axis] >= self.n_cells[axis]
                    else:
                        on = I[axis] <= 0
                    if on:
                        if ti.static(cond == STICKY):
                            v = ti.Vector.zero(float, dim)
                        if ti.static(cond == SLIP):
                            v[axis] = 0.0
                        if ti.static(cond == SEPARATE):
                            if v[axis] * sign < 0:
                                v[axis] = 0.0
            self.grid_v[I] = v
        for p in self.x:  # G2P
            Xp = (self.x[p] - lo) * inv_dx
            base = ti.cast(ti.floor(Xp - 0.5), ti.i32)
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
            self.F[p] = (ti.Matrix.identity(float, dim) + dt * new_C) @ self.F[p]
            vx += new_v[0]
            ti.atomic_max(vmax2, new_v.norm_sqr())
        return ti.Vector([vx / self.x.shape[0], ti.sqrt(vmax2)], dt=ti.f64)

    @ti.kernel
    def observe(self) -> ti.types.vector(2, ti.f64):
        """(centre-of-mass x-velocity, largest particle speed); the particles have equal
        masses, so the first is the mean of v_x."""
        vx = 0.0
        vmax2 = 0.0
        for p in self.v:
            vx += self.v[p][0]
            ti.atomic_max(vmax2, self.v[p].norm_sqr())
        return ti.Vector([vx / self.x.shape[0], ti.sqrt(vmax2)], dt=ti.f64)

    def run(self, end_time: float, frame_every: float | None = None):
        """Step from the current state to ``end_time`` with hpcmpm's time-step rule; returns
        the times and centre-of-mass x-velocities after every step (numpy arrays)."""
        every = frame_every if frame_every and frame_every > 0 else end_time
        t, frame, steps = 0.0, 1, 0
        speed = float(self.observe()[1])
        times, vcm = [], []
        while t < end_time * (1 - 1e-12):
            target = min(frame * every, end_time)
            dt = self.cfl * self.dx / (self.wave_speed + speed)
            clipped = t + dt >= target * (1 - 1e-12)
            if clipped:
                dt = target - t
            vx, speed = self.substep(dt)
            t += dt
            if clipped:
                t = target
                frame += 1
            steps += 1
            times.append(t)
            vcm.append(vx)
        self.steps = steps
        return np.array(times), np.array(vcm, dtype=np.float64)

    def positions(self) -> np.ndarray:
        return self.x.to_numpy()

    def velocities(self) -> np.ndarray:
        return self.v.to_numpy()

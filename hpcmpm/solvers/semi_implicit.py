"""The semi-implicit MPM step (000 §3.4, §5.5, appendix A; Stomakhin 2013; Gast 2015).

The grid velocity of the step minimises

    E(v) = 1/2 sum_i m_i |v_i - v*_i|^2 + sum_p e_p(L_p(v)),   v* = v^n + dt g,
    L_p(v) = sum_i v_i (grad w_ip)^T                              (weights at x^n)

over the unknowns (owned grid nodes with mass; walls, colliders and prescribed sets fix some
directions). grad E = 0 is backward Euler for what e_p makes implicit (elasticity,
viscosity), with the plastic flow explicit: e_p(L) is the material's incremental potential at
its state of t^n (`Material.implicit_energy` and its derivatives; 000 eq. 5.10-5.14 with the
issue's corrections). Its gradient and Hessian-vector product on the grid are

    g_i      = m_i (v_i - v*_i) + sum_p G_p grad w_ip,        G_p = de_p/dL_p
    (H u)_i  = m_i u_i + sum_p D^2 e_p[dL_p(u)] grad w_ip,     dL_p(u) = sum_j u_j grad w_jp^T

(`hpcmpm.kernels.implicit`). ``solver.mode``: "linearized" takes one Newton step from the
explicit predictor v* (Stomakhin 2013), "newton" iterates with a backtracking line search on E
(+inf where a material's state would be inadmissible) until |g| <= newton_tolerance |M v*|
(Gast 2015; 000 §5.7; ``solver.newton_stop = "galilean"``: `_newton_reference`). Each Newton
step solves P H P dv = -P g by preconditioned conjugate gradients (Jacobi: the exact
diagonal of H, or none) to a relative tolerance; P is the
constraint mask. A CG that stops on negative curvature (a non-convex energy) is run again with
every particle tangent projected onto a positive semi-definite one (`_convexify`), and the
linearized step is halved where it would make a state inadmissible or raise E. Walls and
colliders with Coulomb friction act after the solve on the velocity each contact node would
have without its reaction force, so friction takes mu times the normal impulse the contact
carried, as in the explicit step (`_release_reactions`).

Distributed: the CG vectors live on owned nodes; H u is "fill ghosts of u -> particle
contraction -> material Hessian -> scatter -> sum ghosts to owners"; the dot products of an
iteration travel in one allreduce (Chronopoulos-Gear CG); no grid vector is gathered.

Time step: advection only (000 §5.5 removes the elastic and viscous limits), the largest dt
with (|v|max + |g| dt) dt <= cfl dx, where |v|max includes kinematic colliders and prescribed
sets: a fluid at rest under gravity starts with dt = sqrt(cfl dx / |g|) and follows its speed.
A scene where nothing moves and nothing drives (|v| = |g| = 0, no moving boundary) gets the
explicit wave-speed bound for that step unless it caps dt itself (simulation.max_dt / dt).
"""

from __future__ import annotations

import logging
import math
from typing import ClassVar

import numpy as np

from ..boundaries import Collider, PrescribedSet
from ..boundaries.colliders import HALF_SPACE, SPHERE, BOX
from ..errors import InstabilityError, SceneError
from ..kernels.grid import update_velocity
from ..kernels.implicit import (CONTRACT, HESSIAN_PRODUCT, SCATTER_DIAGONAL, SCATTER_TENSOR,
                                add_inertia, add_mass_times, add_mass_times_active, cg_dots,
                                cg_update, constrain, inverse_diagonal, multiply, project,
                                project_tangents_psd, release_reactions, residual_active,
                                stiffness_ratio)
from ..kernels.tangent import index_table, packed_size
from ..kernels.transfer import FLIP, MLS, static
from ..state import VECTOR
from .explicit import explicit_limits

log = logging.getLogger(__name__)

# Newton (mode "newton"): iterations and line-search halvings before the step is declared
# failed; Armijo's sufficient-decrease constant.
NEWTON_MAX_ITERATIONS = 50
LINE_SEARCH_HALVINGS = 30
# E evaluated at the same velocity on another rank count or in another order differs by
# round-off relative to its magnitude; a linearized step may not raise E by more.
ENERGY_ROUNDOFF = 1e-12
ARMIJO = 1e-4
# Newton stops when the step's predicted decrease |g . dx| is below this fraction of |E|: E is
# a sum of per-particle terms of magnitude V0 (mu + lambda) whose round-off exceeds such a
# decrease, so the line search could not tell a better point and would halve 30 times in
# vain (measured: the Bingham channel's first step at dx = 1/64, |g . dx| = 5e-18 against
# E = 1.9e-4, 30 eps |E|, while |g| = 1.9e-9 sat just above newton_tolerance |M v*|). The
# full step is still taken when admissible: its change is below what E resolves.
ENERGY_RESOLUTION = 1e-12
# And when a line search fails, its error measured (`_line_search`): a predicted decrease
# below this multiple of it is unresolved too.
ENERGY_NOISE_MARGIN = 100.0
# Inexact Newton (Eisenstat & Walker 1996, "choice 2"): the k-th linear solve stops at the
# relative residual eta_k = min(EW_ETA0, EW_GAMMA (|g_k|/|g_{k-1}|)^2) (never below
# solver.tolerance; their safeguard against a too small eta cannot act below EW_ETA0 = 1e-3),
# eta_0 = EW_ETA0, and never below NEWTON_CG_FRACTION of Newton's own target |g| <= newton_tolerance |M v*|:
# on a quadratic E the next gradient is the residual, so a tighter solve buys nothing
# Newton's test can see, and while the gradient is far from it the error of a Newton step
# is the nonlinearity's (the plastic return), which the next iteration removes. Measured on
# the Bingham channel (dx = 1/64, t in [0, 1], 50 steps): 22964 CG iterations with every
# solve to |r| <= 1e-8 |b|, 17957 with the Newton floor alone, 16114 with eta_0 = 1e-3
# (15779 at 1e-2 for more Newton iterations, 16796 at 1e-4); the profile at t = 1 is
# unchanged within the Newton tolerance.
NEWTON_CG_FRACTION = 0.1
EW_ETA0 = 1e-3
EW_GAMMA = 0.9
# Restarts of CG from its iterate when the true residual misses the tolerance that the
# recursively updated one met (the recurrences drift by round-off at tight tolerances).
CG_RESTARTS = 3
# A linearized solve stops once |r| <= ROUNDOFF_RESIDUAL S |M v*| (`_cg`): 64 eps, the
# round-off of b relative to the size of its terms (S |M v*|: a Hessian-sized operator applied
# to v*), with a margin for the sums of 9 to 27 products in each term. Measured on pie_2d's
# flight (S = 2e5, the pie stress-free at 3 m/s): |b| grew from 0.03 to 78 eps S |M v*| over
# its first 0.07 s; the solve took 7 CG iterations in those 68 steps, 26 867 without this stop.
ROUNDOFF_RESIDUAL = 64 * float(np.finfo(float).eps)

VECTORS = ("velocity_star", "gradient", "inverse_diagonal", "cg_x", "cg_r", "cg_u", "cg_w",
           "cg_p", "cg_s")


class SolverFailure(InstabilityError):
    """The implicit solve did not converge (CG or Newton): exit code 3 like any instability."""


class SemiImplicitIntegrator:
    """Backward Euler in the elastic and viscous stress, explicit plastic flow (000 §5.5)."""

    name: ClassVar[str] = "semi_implicit"
    needs_velocity_gradient: ClassVar[bool] = True

    def __init__(self, sim):
        self.sim = sim
        spec = sim.scene.solver
        self.mode = spec.mode
        self.jacobi = spec.preconditioner == "jacobi"
        self.tolerance = float(spec.tolerance)
        self.max_iterations = int(spec.max_iterations)
        self.newton_tolerance = float(spec.newton_tolerance)
        self.galilean_newton = spec.newton_stop == "galilean"
        problems = []
        for i, material in enumerate(sim.materials):
            if material.on_grid and not getattr(material, "implicit", False):
                problems.append(f"{sim.scene.path}: materials[{i}].type: {material.name!r} "
                                f"has no semi-implicit energy; use simulation.integrator = "
                                f"'explicit'")
        if problems:
            raise SceneError(problems)
        self._mls = static(sim.scheme == MLS)
        self._frictional: bool | None = None  # the boundaries are built after the integrator
        self._declared = False
        self._shape3 = None
        self._scratch_n = -1
        self._T = None
        self._tangent_ready = False
        self._diagonal_ready = False  # grid "inverse_diagonal" is of the current tangents
        # Statistics: per step, and the window since the last `diagnostics()` call.
        self.last_step: dict[str, float] = {}
        self._window: list[tuple[int, int]] = []
        self.negative_curvature = 0
        self.halved_steps = 0
        self.convexified = 0  # tangents made positive semi-definite (`_convexify`), all ranks
        self._warned_curvature = False

    # -- the step ---------------------------------------------------------------------------
    def grid_step(self, sim, dt: float) -> None:
        """The step's grid part (`Simulation.step` runs the rest): P2G, the solve, G2P and
        the state update."""
        sim.fit_grid()
        sim.scatter_mass_momentum()  # m_i, m_i v_i^n (000 §3.4); no stress: the solve has it
        sim.scatter_forces(dt)  # extensions' particle forces, explicit
        sim.sum_ghosts()
        self.solve(sim, dt)  # v_hat = argmin E (000 §5.5), into grid "velocity"
        sim.fill_ghosts()
        sim.remember_volumes()  # volume_averaging: x^n, J^n for the average below
        sim.gather(dt)  # v, C, x <- x + dt v; L_p = sum_i v_i grad w_ip^T stored
        sim.update_states(dt)  # b_E / F from L over dt, plastic flow with the same L
        sim.average_volumes()  # volume_averaging: the step's change of J, grid-averaged

    @staticmethod
    def scratch_bytes_per_particle(dim: int) -> int:
        """Per-particle arrays of the solve, all at the particles' capacity: L, G, dL, dG
        (d x d each), the tangents T (the upper triangle of d^2 x d^2, `_tangent`) and, while
        the Jacobi diagonal is built, K (d x d x d): 864 B in 3D (of which the tangents
        360), 272 B in 2D."""
        return 8 * (4 * dim * dim + packed_size(dim * dim) + dim ** 3)

    def stable_dt(self, sim, speed: float) -> float:
        """Advection bound (module docstring): the largest dt with
        ``(v + |g| dt) dt <= cfl dx``, v = max(|v_p|, kinematic boundary speed), and no more
        than the explicit limit of what this step integrates explicitly: the materials off the
        grid (peridynamic bodies with integration = "pd", stepped by their bond forces) and
        the step extensions. Measured: an off-grid PMB body (E = 1e8) beside a
        semi-implicit neo-Hookean block took the advection step (0.01, 144 times its bound of
        6.9e-5) and flew apart to 265 m/s in 2 steps while the run reported success; with the
        bound it takes 289 steps to t = 0.02, as the explicit run does, at 1.08 m/s."""
        off_grid = [m for m in sim.materials if not m.on_grid]
        return min(self._advection_dt(sim, speed), explicit_limits(sim, off_grid))

    def _advection_dt(self, sim, speed: float) -> float:
        budget = sim.scene.cfl * sim.dx
        v = max(float(speed), kinematic_speed(sim))
        g = float(np.linalg.norm(sim.gravity))
        if g > 0.0:
            dt = 2.0 * budget / (v + math.sqrt(v * v + 4.0 * g * budget))
        elif v > 0.0:
            dt = budget / v
        else:
            dt = math.inf
        if not math.isfinite(dt) and sim.scene.dt is None and sim.scene.max_dt is None:
            c = sim.max_wave_speed()
            dt = budget / c if c > 0.0 else sim.scene.end_time
        return dt

    def diagnostics(self) -> dict[str, float]:
        """CG iterations per step (mean, max) and Newton iterations per step (mean) over the
        steps since the previous call (a run calls it at every frame), the negative
        curvature stops, the linearized steps halved (admissibility, energy) and the
        particle tangents made positive semi-definite after such a stop, so far. The same
        on every rank."""
        window, self._window = self._window, []
        cg = [c for c, _ in window] or [0]
        newton = [n for _, n in window] or [0]
        return {"cg_iterations_mean": float(np.mean(cg)), "cg_iterations_max": float(max(cg)),
                "newton_iterations_mean": float(np.mean(newton)),
                "cg_negative_curvature": float(self.negative_curvature),
                "halved_steps": float(self.halved_steps),
                "convexified_tangents": float(self.convexified)}

    # -- the solve --------------------------------------------------------------------------
    def solve(self, sim, dt: float) -> None:
        """Minimise E over the unknowns; the result goes to grid "velocity"."""
        if self._frictional is None:
            self._frictional = any(getattr(b, "frictional", False) for b in sim.boundaries)
        with sim.timers("solve_setup"):
            self._prepare(sim, dt)
        cg_total = 0
        newton_steps = 0
        self._halvings = 0
        line_search = self.mode == "newton"
        self._rested = False
        self._unresolved = False
        energy = self._start_energy(sim, dt) if line_search else 0.0
        reference = None
        g_previous = None
        for newton_steps in range(1, NEWTON_MAX_ITERATIONS + 1):
            self._gradient(sim, dt)
            gg, vv = self._dots(sim, [("gradient", "gradient"),
                                      ("velocity_star", "velocity_star")], (0, 2))
            if not math.isfinite(gg) and not line_search and not self._rested:
                # v* itself inverts a particle (a hard impact at a large dt): linearize at
                # the constrained components alone, free ones at rest (Stomakhin 2013's
                # x_hat = x), where every state is the admissible state of t^n.
                self._rest_free_components()
                self._rested = True
                continue
            if not math.isfinite(gg):
                raise SolverFailure(
                    f"the implicit solve met an inadmissible material state (J, det b or tr b "
                    f"<= 0: a non-finite gradient) at step {sim.step_index}, t={sim.time:.6g}. "
                    f"Hint: lower simulation.max_dt or simulation.cfl, or use solver.mode = "
                    f"'newton' (its line search keeps every state admissible).")
            if reference is None:
                # |M (v^n + dt g)|; a scene at rest without gravity falls back on |g_0|.
                reference = math.sqrt(vv) if vv > 0.0 else math.sqrt(gg)
                if not line_search:
                    deformation = self._deformation_momentum(sim, vv)
                elif self.galilean_newton:
                    reference = self._newton_reference(sim, dt, vv) or reference
            if line_search and gg <= (self.newton_tolerance * reference) ** 2:
                newton_steps -= 1
                break
            self._v_grad[:] = -self._v_grad  # the right-hand side -P g (projected already)
            # Linearized: the tolerance is relative to max(|b|, |M (v* - c)|), and never
            # below the round-off of b (see `_cg`). Newton: relative to |b|, but never below
            # NEWTON_CG_FRACTION of Newton's own target (an inexact Newton step: Eisenstat &
            # Walker 1996).
            if line_search:
                floor = (NEWTON_CG_FRACTION * self.newton_tolerance * reference) ** 2
                gnorm = math.sqrt(gg)
                if g_previous is None:
                    eta = EW_ETA0
                else:
                    eta = min(EW_GAMMA * (gnorm / g_previous) ** 2, EW_ETA0)
                eta = max(eta, self.tolerance)
                g_previous = gnorm
                roundoff = 0.0
            else:
                floor, eta = (self.tolerance * deformation) ** 2, self.tolerance
                roundoff = ROUNDOFF_RESIDUAL * math.sqrt(vv)
            iterations, curved = self._cg(sim, dt, "gradient", floor, eta, roundoff)
            if curved:
                # The energy is not convex here: the CG's direction is only trusted up to
                # where it stopped. Solve again with every tangent made positive
                # semi-definite (`_convexify`): a descent step of a convex model.
                self._convexify(sim, dt)
                more, curved = self._cg(sim, dt, "gradient", floor, eta, roundoff)
                iterations += more
            cg_total += iterations
            if not line_search:
                self._admissible_step(sim, dt)
                break
            energy = self._line_search(sim, dt, energy, curved and iterations == 0)
            if self._unresolved:
                break
        else:
            raise SolverFailure(
                f"Newton did not converge in {NEWTON_MAX_ITERATIONS} iterations at step "
                f"{sim.step_index}, t={sim.time:.6g} (|grad E| = {math.sqrt(gg):.3e}, target "
                f"{self.newton_tolerance * reference:.3e}). Hint: lower simulation.max_dt or "
                f"raise solver.newton_tolerance (now {self.newton_tolerance:g}).")
        if self._frictional:
            self._release_reactions(sim, dt)
        with sim.timers("solve_setup"):
            # Walls and colliders once more: a node the solve pushed into an obstacle it was
            # leaving at v* (free in the mask) is stopped like in the explicit step; a
            # constrained node is unchanged by it (or, with friction, gets its normal part
            # removed and the Coulomb friction of its reaction: `_release_reactions`).
            sim.apply_grid_boundaries(sim.grid["velocity"], dt)
        self.last_step = {"cg_iterations": cg_total, "newton_iterations": newton_steps,
                          "halvings": self._halvings}
        self._window.append((cg_total, newton_steps))

    def _prepare(self, sim, dt: float) -> None:
        """v* = (p + dt f_ext)/m + dt g, the unknowns' mask, the constraints at v*, the
        initial guess v0 = v* with the boundary conditions applied, and particle scratch."""
        grid, d = sim.grid, sim.dim
        names = VECTORS + ("velocity_trial",)
        if not self._declared:
            for name in names:
                grid.declare(name, VECTOR)
            self._declared = True
        flat = {name: grid[name].reshape(-1, d) for name in names + ("velocity",)}
        self._v_velocity, self._v_star = flat["velocity"], flat["velocity_star"]
        self._v_grad, self._v_x = flat["gradient"], flat["cg_x"]
        self._flat = flat
        mass = grid["mass"].reshape(-1)
        self._mass = mass
        impulse = grid["impulse"] if sim.split_force else grid["momentum"]
        flip = sim.scheme == FLIP
        update_velocity(mass, grid["momentum"].reshape(-1, d), impulse.reshape(-1, d),
                        sim.split_force, sim.gravity[:d], dt, self._v_star,
                        (grid["velocity_old"] if flip else grid["velocity_star"]).reshape(-1, d),
                        flip)
        # Unknowns: owned nodes with mass.
        free = np.zeros(grid.shape)
        owned = sim.domain.owned_slices(grid)
        free[owned] = grid["mass"][owned] > 0.0
        self._free = free.reshape(-1)
        self._active = np.flatnonzero(self._free)  # `cg_update`: the CG sweeps these alone
        if self.mode == "newton":  # the line search's start cap (`_line_search`)
            self._total_mass = sim.domain.sum(float(grid["mass"][owned].sum()))
        # Constraint directions at the trial velocity v*.
        shape3 = tuple(grid.shape) + (1,) * (3 - d)
        if self._shape3 != shape3:
            self._shape3 = shape3
            self._count = np.zeros(shape3, dtype=np.int64)
            self._basis = np.zeros(shape3 + (3, 3))
        count, basis = self._count, self._basis
        count.fill(0)
        star = grid["velocity_star"]
        for condition in sim.boundaries:
            condition.constrain(star, grid.origin, sim.dx, sim.domain_lo, sim.time, dt,
                                grid["mass"], basis, count)
        for clamp in sim.prescribed:
            clamp.constrain(star, grid.origin, sim.dx, sim.domain_lo, sim.time, dt, grid,
                            basis, count)
        nodes = np.flatnonzero(count.reshape(-1))
        self._nodes = nodes
        self._node_basis = np.ascontiguousarray(basis.reshape(-1, 3, 3)[nodes])
        self._node_count = np.ascontiguousarray(count.reshape(-1)[nodes])
        self._v_velocity[:] = self._v_star
        sim.apply_grid_boundaries(grid["velocity"], dt)
        # Particle scratch and each on-grid material's slice.
        p = sim.particles
        if self._scratch_n < p.n:
            n = p.capacity
            self._L = np.zeros((n, d, d))
            self._G = np.zeros((n, d, d))
            self._dL = np.zeros((n, d, d))
            self._dG = np.zeros((n, d, d))
            self._T = np.zeros((n, packed_size(d * d)))  # the tangents (`_tangent`)
            self._scratch_n = n
        self._ranges = sim.grid_ranges()
        self._slices = [(sim.materials[g], sim.material_fields(g), *sim.group_slices[g])
                        for g in sim._on_grid if sim.group_slices[g][1] > sim.group_slices[g][0]]

    # -- grid-level pieces ------------------------------------------------------------------
    def _project(self, name: str) -> None:
        project(self._flat[name], self._free, self._nodes, self._node_basis, self._node_count)

    def _constrain(self, name: str) -> None:
        """`_project` on the unknowns alone (the other nodes are left as they are)."""
        constrain(self._flat[name], self._free, self._nodes, self._node_basis,
                  self._node_count)

    def _cg_dots(self, sim) -> np.ndarray:
        """(r.u, w.u, r.r) of the CG over all ranks, in one allreduce (`cg_dots`)."""
        f = self._flat
        with sim.timers("solve_dots"):
            local = np.array(cg_dots(self._active, f["cg_r"], f["cg_u"], f["cg_w"]))
            return sim.domain.sum(local)

    def _dots(self, sim, pairs, weights=None):
        with sim.timers("solve_dots"):
            return sim.domain.dots(sim.grid, pairs, weights)

    def _contract(self, sim, name: str, L: np.ndarray) -> None:
        """L_p(u) for the grid vector ``name`` (its ghosts filled first)."""
        grid = sim.grid
        with sim.timers("solve_halo"):
            sim.domain.fill_ghosts(grid, name)
        with sim.timers("solve_contract"):
            x = sim.particles["x"]
            for start, stop in self._ranges:
                if stop > start:
                    CONTRACT[sim.dim](x[start:stop], grid[name], self._mls, sim._static_order,
                                      sim.dinv_factor, sim.dx, sim.domain_lo, grid.origin,
                                      L[start:stop])

    def _scatter(self, sim, T: np.ndarray, name: str) -> None:
        """grid[name] = sum_p T_p grad w_ip, summed to the owners."""
        grid = sim.grid
        with sim.timers("solve_scatter"):
            out = grid[name]
            out.fill(0.0)
            x = sim.particles["x"]
            for start, stop in self._ranges:
                if stop > start:
                    SCATTER_TENSOR[sim.dim](x[start:stop], T[start:stop], 1.0, self._mls,
                                            sim._static_order, sim.dinv_factor, sim.dx,
                                            sim.domain_lo, grid.origin, out)
        with sim.timers("solve_halo"):
            sim.domain.sum_ghosts_to_owners(grid, name)

    def _gradient(self, sim, dt: float) -> None:
        """grid "gradient" = P g at the current velocity; keeps L_p(v) for the Hessian (and,
        for `_release_reactions` in the linearized mode, g itself)."""
        self._full_gradient(sim, dt)
        with sim.timers("solve_vector"):
            if self._frictional and self.mode == "linearized":
                self._g0 = self._v_grad.copy()
            self._project("gradient")

    def _full_gradient(self, sim, dt: float) -> None:
        """grid "gradient" = g at the current velocity on the unknowns' nodes, constrained
        directions included."""
        self._contract(sim, "velocity", self._L)
        self._tangent_ready = self._diagonal_ready = False
        with sim.timers("solve_material"):
            for material, fields, start, stop in self._slices:
                try:
                    material.implicit_gradient(fields, self._L[start:stop], dt,
                                               self._G[start:stop])
                except ZeroDivisionError:  # a degenerate state (det = 0): inadmissible
                    self._G[start:stop] = math.nan
        self._scatter(sim, self._G, "gradient")
        with sim.timers("solve_vector"):
            add_inertia(self._v_grad, self._mass, self._v_velocity, self._v_star, self._free)

    def _release_reactions(self, sim, dt: float) -> None:
        """Coulomb friction needs the normal impulse, which the solve holds as a constraint
        reaction: at the solution the constrained components of the gradient are the
        reaction forces (M (v - v*) + dPhi/dv = R). Each constrained node gets the velocity
        it would have without them (`release_reactions`), so the walls and colliders that
        act next remove its normal part and take friction * |v.n| off its tangential part
        exactly as the explicit step does with its trial velocity. Without this the
        tangential velocity is a free unknown of the solve and friction never acts (the
        boundaries met v* only, and after the solve v.n = 0). Costs one more gradient
        (Newton) or Hessian product (linearized) and an energy per step, only in scenes
        with a frictional separate wall or collider."""
        if self.mode == "linearized":
            # The step solved the linear model g(v) = g(v0) + H (v - v0) at v0 (Stomakhin
            # 2013): its reactions are that model's at the step the solve took (alpha dv),
            # before the walls and colliders met it. The full gradient at the final v
            # differs by the linearization error, and a node the boundaries stop after the
            # solve (free in the mask at v*, driven into the obstacle) would pass its stop
            # through H to its neighbours' reactions (measured on a sliding block at cfl
            # 0.1: the floor's load overstated by 9 %, the deceleration by 13 %).
            f = self._flat
            np.multiply(f["cg_x"], self._alpha, out=f["cg_p"])
            self._hessian(sim, dt, "cg_p", "cg_u", projected=False)
            np.add(self._g0, f["cg_u"], out=self._v_grad)
        else:
            self._full_gradient(sim, dt)
        solved = self._v_velocity
        trial = self._flat["velocity_trial"]
        with sim.timers("solve_vector"):
            trial[:] = solved
            release_reactions(trial, self._v_grad, self._mass, self._free,
                              self._nodes, self._node_basis, self._node_count)
            sim.apply_grid_boundaries(sim.grid["velocity_trial"], dt)
            change = trial - solved
        # Friction stops contact nodes the solve let slide: keep the step admissible, as
        # `_admissible_step` does, by halving that change where it would invert a particle
        # (the solved velocity stays if no fraction of it is admissible).
        self._backtrack(sim, dt, solved, change)

    def _hessian(self, sim, dt: float, src: str, dst: str, projected: bool = True,
                 unknowns_only: bool = False) -> None:
        """grid[dst] = P H P grid[src] at the L of the last `_gradient`: fill the ghosts of
        src, one fused particle loop with the tangents (`_tangent`), sum to the owners.
        ``projected=False``: H grid[src] on the unknowns' nodes, constrained directions
        included. ``unknowns_only`` (the CG's products): grid[dst] is set on the unknowns
        alone; other nodes keep the particles' partial sums instead of zeros."""
        self._tangent(sim, dt)
        grid = sim.grid
        with sim.timers("solve_halo"):
            sim.domain.fill_ghosts(grid, src)
        with sim.timers("solve_product"):
            out = grid[dst]
            out.fill(0.0)
            x, T = sim.particles["x"], self._T
            for start, stop in self._ranges:
                if stop > start:
                    HESSIAN_PRODUCT[sim.dim](x[start:stop], T[start:stop], grid[src],
                                             self._mls, sim._static_order, sim.dinv_factor,
                                             sim.dx, sim.domain_lo, grid.origin, out)
        with sim.timers("solve_halo"):
            sim.domain.sum_ghosts_to_owners(grid, dst)
        with sim.timers("solve_vector"):
            if unknowns_only:
                add_mass_times_active(self._flat[dst], self._mass, self._flat[src],
                                      self._active)
                if projected:
                    self._constrain(dst)
            else:
                add_mass_times(self._flat[dst], self._mass, self._flat[src], self._free)
                if projected:
                    self._project(dst)

    def _tangent(self, sim, dt: float) -> None:
        """T_p[ab, ce] = d^2 e_p / dL_ab dL_ce at the L of the last `_gradient`, from each
        material's `implicit_tangent`: d^2 Hessian products with the unit directions E_ce,
        or one pass for the b_E models (once per linearization; a CG solve then applies H
        many times at the same L). Exact: D^2 e_p[dL] is linear in dL, so T_p : dL is the
        material's product up to round-off (tested); a material's product recomputes its
        plastic return and b_hat(L) from L each time, where T_p is d^4 multiply-adds.
        Memory: the upper triangle, d^2 (d^2 + 1) / 2 doubles per particle (80 B in 2D,
        360 B in 3D; kernels/tangent.py)."""
        if self._tangent_ready:
            return
        T = self._T
        with sim.timers("solve_material"):
            for material, fields, start, stop in self._slices:
                material.implicit_tangent(fields, self._L[start:stop], dt,
                                          self._dL[start:stop], self._dG[start:stop],
                                          T[start:stop])
        self._tangent_ready = True

    def _convexify(self, sim, dt: float) -> None:
        """Project the tangents of this linearization onto positive semi-definite ones
        (`project_tangents_psd`; Teran et al. 2005), after a CG stopped on negative
        curvature: H is then positive definite and the CG that follows converges to a
        descent direction of E. Only particles with a negative eigenvalue change.
        Measured on pie_2d: the cream compressed under the crust at t = 0.263 made the
        CG stop (p.Hp = -1.1e-4 after 158 iterations); the step it returned raised E 25x
        and sent particles to 500 m/s, collapsing the time step to 1e-6; the run stopped
        on an inadmissible state 0.008 s later."""
        self._tangent(sim, dt)
        with sim.timers("solve_material"):
            changed = project_tangents_psd(self._T[:sim.particles.n])
        self._diagonal_ready = False
        self.convexified += sim.domain.sum(int(changed))

    def _jacobi(self, sim, dt: float, stiffness: bool = False) -> float:
        """grid "inverse_diagonal" = 1 / diag(H) on the unknowns (`inverse_diagonal`), or
        the identity there without a preconditioner. Returns the stiffness ratio
        max diag(H)_i / m_i agreed by all ranks (`stiffness_ratio`) when ``stiffness``,
        else 1. diag(H) is computed when either needs it, and the preconditioner is kept
        while the tangents are the same (Newton's galilean stop computes it, with S, before
        the first CG of a step needs it).

        The material part needs K_p[a, b, c] = d^2 e_p / dL_ab dL_ac, a part of the tangent
        T_p (`_tangent`), then one scatter."""
        if self._diagonal_ready and not stiffness:
            return 1.0
        self._diagonal_ready = True
        out = self._flat["inverse_diagonal"]
        material = self._material_diagonal(sim, dt) if self.jacobi or stiffness else None
        if self.jacobi:
            inverse_diagonal(material, self._mass, self._free, out)
        else:
            inverse_diagonal(np.zeros_like(out), self._mass, self._free, out)
            out *= self._mass[:, None]  # no preconditioner: the identity on the unknowns
        if not stiffness:
            return 1.0
        return sim.domain.max(stiffness_ratio(material, self._mass, self._free))

    def _material_diagonal(self, sim, dt: float) -> np.ndarray:
        """The material part of diag(H) on the owned nodes, (N, d), in grid "cg_w" (scratch)."""
        d, n = sim.dim, sim.particles.n
        self._tangent(sim, dt)
        # K[p, a, b, c] = T_p[ab, ac], read from the packed rows.
        K = self._T[:n][:, self._diagonal_blocks(d)]
        grid = sim.grid
        diagonal = grid["cg_w"]
        with sim.timers("solve_scatter"):
            diagonal.fill(0.0)
            x = sim.particles["x"]
            for start, stop in self._ranges:
                if stop > start:
                    SCATTER_DIAGONAL[d](x[start:stop], K[start:stop], self._mls,
                                        sim._static_order, sim.dinv_factor, sim.dx,
                                        sim.domain_lo, grid.origin, diagonal)
        with sim.timers("solve_halo"):
            sim.domain.sum_ghosts_to_owners(grid, "cg_w")
        return self._flat["cg_w"]

    @staticmethod
    def _diagonal_blocks(d: int) -> np.ndarray:
        """(d, d, d) packed positions of T[ab, ac] (kernels/tangent.py)."""
        table = index_table(d * d)
        a, b, c = np.meshgrid(np.arange(d), np.arange(d), np.arange(d), indexing="ij")
        return table[a * d + b, a * d + c]

    def _deformation_momentum(self, sim, vv: float) -> float:
        """|M (v* - c)| over the unknowns' nodes, c = sum m^2 v* / sum m^2 the uniform
        velocity that minimises it (the M-weighted norm of `_dots`), from vv = |M v*|^2:
        v*'s momentum less its uniform translation (`_cg`). One allreduce. The difference
        vv - |sum m^2 v*|^2 / sum m^2 loses (|c| / |v* - c|)^2 eps of its value: 1e-8 where
        the translation is 1e4 times the rest, and below the round-off stop of `_cg` where
        the rest is round-off itself."""
        moment, weight = sim.domain.weighted_sum(sim.grid, "velocity_star", 2)
        if weight <= 0.0:
            return 0.0
        return math.sqrt(max(vv - float(moment @ moment) / weight, 0.0))

    def _precondition(self, src: str, dst: str) -> None:
        multiply(self._flat["inverse_diagonal"].reshape(-1), self._flat[src].reshape(-1),
                 self._flat[dst].reshape(-1))
        self._project(dst)

    # -- conjugate gradients ----------------------------------------------------------------
    def _cg(self, sim, dt: float, rhs: str, floor: float = 0.0,
            relative: float | None = None, roundoff: float = 0.0) -> tuple[int, bool]:
        """Solve P H P x = b (b in grid[rhs], projected) into "cg_x" by preconditioned CG in
        the Chronopoulos-Gear form: one Hessian product and one allreduce (of r.u, w.u,
        r.r) per iteration. Stops at |r|^2 <= max(tolerance^2 |b|^2, floor,
        (roundoff S)^2), S the stiffness ratio max diag(H)_i / m_i (`stiffness_ratio`; asked
        only when roundoff > 0); then checks the true residual b - H x and restarts from x
        if it misses (at most `CG_RESTARTS` times). Returns the iterations and whether it
        stopped on negative curvature (p.Hp <= 0: x is kept as it was, a descent direction
        when non-zero).

        The linearized solve passes floor = (tolerance |M (v* - c)|)^2, c the m^2-weighted
        mean of v* (`_deformation_momentum`): a residual that small changes the velocities
        by about tolerance |v* - c|, so the tolerance is relative to the larger of the
        right-hand side and the momentum of the motion that is not a uniform translation.
        Galilean invariant: a uniform velocity added to a scene leaves b and the floor as
        they were (apart from round-off), so it neither loosens nor tightens the solve.
        And roundoff = `ROUNDOFF_RESIDUAL` |M v*|: b = -P g(v*) is a sum of Hessian-sized
        terms applied to v*, so its round-off is about eps S |M v*|; a body in free flight
        (b at that round-off) would otherwise have its round-off solved to the tolerance,
        hundreds of iterations on a stiff crust for nothing."""
        f = self._flat
        x, r, u, w, p, s = (f[k] for k in ("cg_x", "cg_r", "cg_u", "cg_w", "cg_p", "cg_s"))
        b, inverse, active = f[rhs], f["inverse_diagonal"], self._active
        # Zero off the unknowns (b is projected); `cg_update` then writes the unknowns alone.
        x[:] = 0.0
        r[:] = b
        (bb,) = self._dots(sim, [(rhs, rhs)])
        relative = self.tolerance if relative is None else relative
        target = max(relative * relative * bb, floor)
        if bb <= target:
            return 0, False
        stiffness = float(self._jacobi(sim, dt, roundoff > 0.0))
        guard = float(roundoff) * stiffness
        if not math.isfinite(guard * guard):
            # H's diagonal beyond the float range: the round-off stop would be inf and the
            # solve skipped, the step taken at v* as if the material had no stiffness
            # (measured: toothpaste_3d with lambda = 1e308 ran on, its paste falling freely).
            self._stiffness_failure(sim, stiffness)
        target = max(target, guard * guard)
        if bb <= target:
            return 0, False
        iterations = restarts = 0
        while True:
            self._precondition("cg_r", "cg_u")  # the whole block: u is zero off the unknowns
            self._hessian(sim, dt, "cg_u", "cg_w", unknowns_only=True)
            gamma, delta, rr = self._cg_dots(sim)
            first = True
            gamma_old = alpha = math.nan  # the previous iteration's; not read on the first
            while rr > target:
                if iterations >= self.max_iterations or not math.isfinite(rr):
                    self._fail(sim, rr, bb, iterations)
                if first:
                    beta, curvature = 0.0, delta
                else:
                    beta = gamma / gamma_old
                    curvature = delta - beta * gamma / alpha
                if not curvature > 0.0:
                    self.negative_curvature += 1
                    if not self._warned_curvature and sim.domain.rank == 0:
                        log.warning("CG stopped on negative curvature at step %d (p.Hp = %.3e "
                                    "after %d iterations); the energy is not convex there",
                                    sim.step_index, curvature, iterations)
                        self._warned_curvature = True
                    return iterations, True
                alpha = gamma / curvature
                with sim.timers("solve_vector"):
                    cg_update(active, first, alpha, beta, u, w, p, s, x, r, inverse)
                    self._constrain("cg_u")
                self._hessian(sim, dt, "cg_u", "cg_w", unknowns_only=True)
                gamma_old = gamma
                gamma, delta, rr = self._cg_dots(sim)
                iterations += 1
                first = False
            # The recursively updated residual met the tolerance: check b - H x.
            self._hessian(sim, dt, "cg_x", "cg_w", unknowns_only=True)
            with sim.timers("solve_vector"):
                residual_active(active, b, w, r)
            rr = self._cg_dots(sim)[2]
            if rr <= target:
                return iterations, False
            if restarts >= CG_RESTARTS:
                self._fail(sim, rr, bb, iterations)
            restarts += 1

    @staticmethod
    def _stiffness_failure(sim, stiffness: float) -> None:
        raise SolverFailure(
            f"the implicit solve's stiffness is beyond the floating-point range at step "
            f"{sim.step_index}, t={sim.time:.6g}: max diag(H)_i / m_i = {stiffness:.3g}. "
            f"Hint: check the materials' moduli and viscosities against their densities.")

    def _newton_reference(self, sim, dt: float, vv: float) -> float:
        """``solver.newton_stop = "galilean"``: Newton stops at |g| <= newton_tolerance R,
        R = max(|M (v* - c)|, ROUNDOFF_RESIDUAL S |M v*| / newton_tolerance), the linear
        stop's two terms (`_cg`): c the uniform part of v*, so a uniform velocity added to
        the scene neither loosens the stop (the issue's |M v*| grows with it: the block of
        tests/verification/test_semi_implicit_galilean.py carried at 300 m/s took 0 Newton
        steps) nor asks for g below its round-off, eps S |M v*| (a body in free flight).
        S needs H's diagonal at the first linearization, which the first CG then reuses
        (`_jacobi`): one more allreduce a step. 0 when v* has no momentum (the caller falls
        back on |g_0|)."""
        stiffness = float(self._jacobi(sim, dt, True))
        roundoff = ROUNDOFF_RESIDUAL * stiffness * math.sqrt(vv)
        if not math.isfinite(roundoff * roundoff):
            self._stiffness_failure(sim, stiffness)
        return max(self._deformation_momentum(sim, vv), roundoff / self.newton_tolerance)

    def _fail(self, sim, rr: float, bb: float, iterations: int) -> None:
        residual = math.sqrt(rr / bb) if math.isfinite(rr) else math.nan
        raise SolverFailure(
            f"CG did not converge at step {sim.step_index}, t={sim.time:.6g}: relative "
            f"residual {residual:.3e} after {iterations} iterations (solver.tolerance "
            f"{self.tolerance:g}, solver.max_iterations {self.max_iterations}). Hint: lower "
            f"simulation.max_dt or simulation.cfl, use solver.preconditioner = 'jacobi', or "
            f"raise solver.max_iterations.")

    # -- Newton (Gast 2015) -----------------------------------------------------------------
    def _energy(self, sim, dt: float, name: str) -> float:
        """E at grid velocity ``name``; +inf when a material finds the state inadmissible."""
        self._contract(sim, name, self._dL)
        local = 0.0
        with sim.timers("solve_material"):
            for material, fields, start, stop in self._slices:
                try:
                    local += material.implicit_energy(fields, self._dL[start:stop], dt)
                except ZeroDivisionError:  # a degenerate state (det = 0): inadmissible
                    local = math.inf
        f = self._flat
        with sim.timers("solve_vector"):
            f["cg_w"][:] = f[name] - self._v_star
            f["cg_w"] *= self._free[:, None]
        (kinetic,) = self._dots(sim, [("cg_w", "cg_w")], (1,))
        total = sim.domain.sum(float(local)) + 0.5 * kinetic
        return total if math.isfinite(total) else math.inf

    def _rest_free_components(self) -> None:
        """Keep the constrained components of grid "velocity" (boundary values), zero the
        free ones."""
        v = self._v_velocity
        free_part = v.copy()
        project(free_part, self._free, self._nodes, self._node_basis, self._node_count)
        v -= free_part

    def _start_energy(self, sim, dt: float) -> float:
        """E at the initial guess; when that is inadmissible, start from the constrained
        components alone (free ones at rest), which moves nothing but the boundaries."""
        energy = self._energy(sim, dt, "velocity")
        if math.isfinite(energy):
            return energy
        self._rest_free_components()
        energy = self._energy(sim, dt, "velocity")
        if not math.isfinite(energy):
            raise SolverFailure(
                f"Newton: no admissible starting velocity at step {sim.step_index}, "
                f"t={sim.time:.6g} (a material state is inadmissible at v* and at rest). "
                f"Hint: lower simulation.max_dt or simulation.cfl.")
        return energy

    def _admissible_step(self, sim, dt: float) -> None:
        """Linearized mode: v += dv, halved until every material state it makes is
        admissible (E finite) once the boundary conditions have acted on it, and E does
        not rise above its value at the start v0 (up to round-off). The full step is taken
        whenever it qualifies, which is every step of a convex, resolved solve: then the
        Newton step of a quadratic model lowers E. The halvings (counted in
        ``last_step["halvings"]``) act where one Newton step would invert a particle (a
        hard impact at a large dt) or where the energy is not convex: a CG stopped on
        negative curvature returns a direction the model trusts too far (measured on
        pie_2d at t = 0.263: E rose 25x in one step, the crust reached 500 m/s and the
        time step collapsed to 1e-6; no step before it raised E). CG iterates are descent
        directions of the model, so a small enough multiple lowers E; when none of
        LINE_SEARCH_HALVINGS does, the smallest admissible one is taken."""
        start = self._v_velocity  # read by `_backtrack` before it writes the result
        e0 = self._energy(sim, dt, "velocity")
        # The walls and colliders act once more on the result (`solve`); check the velocity
        # G2P will see.
        taken = self._backtrack(sim, dt, start, self._v_x, e0 + ENERGY_ROUNDOFF * abs(e0),
                                boundaries=True)
        if taken is None:
            raise SolverFailure(
                f"no admissible velocity along the linearized step at step {sim.step_index}, "
                f"t={sim.time:.6g}. Hint: lower simulation.max_dt or simulation.cfl, or use "
                f"solver.mode = 'newton'.")
        self._alpha, self._halvings = taken
        self.halved_steps += self._halvings > 0

    def _backtrack(self, sim, dt: float, start: np.ndarray, change: np.ndarray,
                   bound: float = math.inf, boundaries: bool = False):
        """grid "velocity" = start + alpha change for the first alpha = 1, 1/2, ... (at most
        LINE_SEARCH_HALVINGS) whose E is finite and at most ``bound``, else for the smallest
        one with E finite; with ``boundaries`` the walls and colliders act on each trial
        first. ``start`` may be grid "velocity" itself: it is written only once the choice is
        made. Returns (alpha, halvings), or None (velocity untouched) when no trial was
        admissible."""
        trial = self._flat["velocity_trial"]
        alpha = 1.0
        fallback = None
        for halving in range(LINE_SEARCH_HALVINGS):
            np.multiply(change, alpha, out=trial)
            trial += start
            if boundaries:
                sim.apply_grid_boundaries(sim.grid["velocity_trial"], dt)
            energy = self._energy(sim, dt, "velocity_trial")
            if math.isfinite(energy):
                if energy <= bound:
                    self._v_velocity[:] = trial
                    return alpha, halving
                fallback = (trial.copy(), alpha, halving)
            alpha *= 0.5
        if fallback is None:
            return None
        self._v_velocity[:] = fallback[0]
        return fallback[1:]

    def _line_search(self, sim, dt: float, energy: float, steepest: bool) -> float:
        """Backtracking from the full Newton step: halve until E decreases enough (Armijo);
        E = +inf (inadmissible) always rejects. Returns the new energy. A step whose
        predicted decrease E cannot resolve (`ENERGY_RESOLUTION`) is taken at the first
        admissible length and sets ``self._unresolved``: Newton has converged to the
        precision of E."""
        f = self._flat
        direction = f["cg_x"]
        if steepest:  # negative curvature at once: the preconditioned gradient direction
            self._precondition("gradient", "cg_x")
        # The slope g . dx ("gradient" holds -P g now) and sum m |dx|^2 in one allreduce.
        pairs, weights = [("cg_x", "gradient"), ("cg_x", "cg_x")], (0, 1)
        slope, kinetic = self._dots(sim, pairs, weights)
        slope = -slope
        if not slope < 0.0:
            direction[:] = f["gradient"]
            slope, kinetic = self._dots(sim, pairs, weights)
            slope = -slope
        trial = f["velocity_trial"]
        # Start no further than a mass-weighted RMS change of dx/dt in the node velocities
        # (one cell of displacement): on an indefinite Hessian the CG direction can be far
        # too long, and halving from 1 would not reach an admissible point. Mass-weighted:
        # a node of negligible mass may carry a direction of hundreds of m/s (measured: 635
        # m/s at a node of 2e-9 kg beside a median of 0.25 m/s in an impact), and capping by
        # the largest node held every Newton step to 1.4 % of its length.
        rms = math.sqrt(kinetic / self._total_mass) if self._total_mass > 0.0 else 0.0
        alpha = min(1.0, sim.dx / (dt * rms)) if rms > 0.0 else 1.0
        unresolved = -slope <= ENERGY_RESOLUTION * abs(energy)
        longest = None  # (alpha, E) of the longest admissible trial
        for _ in range(LINE_SEARCH_HALVINGS):
            np.multiply(direction, alpha, out=trial)
            trial += self._v_velocity
            value = self._energy(sim, dt, "velocity_trial")
            if longest is None and math.isfinite(value):
                longest = (alpha, value)
            slack = 4.0 * np.finfo(float).eps * abs(energy)
            if unresolved and math.isfinite(value):
                self._unresolved = True
                self._v_velocity[:] = trial
                return value
            if value <= energy + ARMIJO * alpha * slope + slack:
                self._v_velocity[:] = trial
                return value
            alpha *= 0.5
        # No halving lowered E. At the last one (alpha ~ 2e-9) E's own change is alpha |g.dx|,
        # nothing, so ``value - energy`` there is what E's evaluation errs by. A full step's
        # predicted decrease within ENERGY_NOISE_MARGIN of that error cannot be seen at any
        # length: Newton has converged to the precision of E, and the longest admissible
        # trial is taken as above (its change of E is within that error too). Measured:
        # channel_hb_2d at one particle per cell on 2 ranks, newton_tolerance 1e-11: E =
        # 3.9e-6 erred by 5.4e-18 (1.4e-12 |E|, the implicit return's own tolerance) against
        # |g.dx| = 6.8e-18, and the run stopped here; on 1 rank it passed by chance.
        # (A shortest trial that is inadmissible says nothing of E's error: that still fails.)
        if math.isfinite(value) and -slope <= ENERGY_NOISE_MARGIN * (value - energy):
            self._unresolved = True
            alpha, value = longest  # the shortest trial is admissible, so there is one
            np.multiply(direction, alpha, out=trial)
            self._v_velocity[:] += trial
            return value
        raise SolverFailure(
            f"Newton line search found no decrease at step {sim.step_index}, t={sim.time:.6g} "
            f"after {LINE_SEARCH_HALVINGS} halvings (E = {energy:.6e}). Hint: lower "
            f"simulation.max_dt or simulation.cfl.")


def kinematic_speed(sim) -> float:
    """Largest speed a collider or prescribed set can impose (|v| + |omega| r, r its reach
    from its centre), for the advection time step: at t = 0 a body at rest held by a
    twisting clamp has |v_p| = 0 but moves at the clamp's speed after one step."""
    speed = 0.0
    span = float(np.linalg.norm(np.asarray(sim.scene.domain_hi) - np.asarray(sim.scene.domain_lo)))
    for condition in sim.boundaries:
        if isinstance(condition, Collider):
            size = condition.size
            d = condition.dim
            if condition.shape == HALF_SPACE:  # anywhere in the domain
                reach = span
            elif condition.shape == SPHERE:
                reach = size[0]
            elif condition.shape == BOX:
                reach = float(np.linalg.norm(size[:d]))
            else:  # cylinder
                reach = math.hypot(size[0], size[1])
            speed = max(speed, float(np.linalg.norm(condition.velocity))
                        + float(np.linalg.norm(condition.omega)) * reach)
    for clamp in sim.prescribed:
        if isinstance(clamp, PrescribedSet):
            corners = np.array([clamp.lower, clamp.upper])
            reach = float(np.linalg.norm(np.abs(corners - clamp.centre0[: sim.dim]).max(axis=0)))
            reach += 2.0 * sim.dx  # the support nodes the clamp moves
            speed = max(speed, float(np.linalg.norm(clamp.velocity))
                        + float(np.linalg.norm(clamp.omega)) * reach)
    return speed

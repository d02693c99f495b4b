"""SPB-MPM: MPM particles that become peridynamic where the grid energy is high (003 ch. 6,
Alg. 3, with the corrections of issue 11). One step extension per scene, for every material
with ``failure = { model = "spb", ... }`` (hpcmpm/materials/failure.py).

What the engine calls, and when:

- ``stress_chunk`` (P2G, per stress chunk of an SPB material; phase "spb_energy"): the energy
  history EE_p = max(EE_p, Phi(sigma+_p)) from the chunk's Kirchhoff stress and the scatter of
  m_p EE_p into the grid field ``spb_energy`` (grid_energy.py, eq. 6.10), summed to owners
  with the engine's mass (turned into G_i on the owners and filled into the ghosts after G2P). With ``coupling =
  "exclusive"`` the stress of PD particles is zeroed before P2G (their internal force is
  their bonds'); ``"additive"`` keeps it (Alg. 3 as printed).
- ``before_state`` (phases "spb_convert", "pd", "spb_retransfer"; after G2P, before the
  materials' state update), with x = x^ = x^n + dt v^ and v = v^ from G2P (MLS:
  x^n = x - dt v):
  1. conversion: an MPM particle of an SPB material whose cell at x^n has a corner node with
     G_i = l0 e_i / m_i >= G_EE becomes PD (field ``model`` 0 -> 1; irreversible; same id,
     same rows: no array is copied). Owners decide from the ghost-summed and filled G_i.
  2. bonds (only once PD particles exist anywhere): each new PD particle gets a half-bond to
     every PD particle (existing or new) with |x0_q - x0_p| < delta + s/2 (PA-HHB partial
     volumes, families.py); a pair whose stretch already exceeds the reach (max_bond_stretch)
     starts broken and counts in the damage. The new particles' ids, x0 and x^ go to every
     rank (one allgather per step with conversions), so both ends of a cross-rank bond build
     it from the same bits; the end that already was PD sends the other end its half-bond.
     Along periodic axes the reference positions move with their particles' wraps by the
     same whole periods (`Domain.wrap_particles`), and the search brings them into the box
     and adds images near its faces (families.shift_into_box, periodic_images), so families
     reach across a face (radius
     below half the period: one image per partner, the scene check).
  3. PD evolution at x^ (Alg. 3 lines 3-21, corrected): K, F^PD = (sum w Y (x) X V) K^-1
     (K^-1 after the sum), sigma^PD from the particle's own material at F^PD (snow at
     F^PD F_P^-1; shock and j2, which keep no total F: their own stress, handed over as
     tau = det(F^PD) sigma, `ImpactMaterial.pd_stress`), T = w P K^-1 X (eq. 6.8 = 4.7 with the P^T correction), force eq. 6.6
     times V_p with Silling's zero-energy-mode control (near a sticky domain wall K, F and
     the force include the clamp's image bonds, clamp.py), v = v^ + dt f/m and x = x^n + dt v
     (line 21 prints x^ + dt v, which advances twice); then failure (energy_failure.py: eq.
     6.11 as printed or the accumulated work; or eq. 4.8), damage and the active half-bond
     counts (the load-balance weights, `add_load`).
  4. "transfer again" (6.3.1): the momentum correction m (v - v^) of the PD particles is
     scattered at x^n, summed to owners, turned into a grid velocity correction (boundary
     conditions applied again) and filled into ghosts; every particle touching a corrected
     node gets C^{n+1} = C^ + D^-1 sum_i w_ip dv_i (x_i - x^n)^T and F^{n+1} = (I + dt
     C^{n+1}) F^n = (I + dt C^{n+1})(I + dt C^)^-1 F (exact algebra, no stored F^n); MPM
     particles keep v^ (as the thesis). In deformation mode "L" (the impact models) G2P
     stored L = C^ and advanced nothing: the re-transfer adds the same increment to L, and
     the materials' state update that follows (F, F_E, s, J, E, plastic return) sees the
     corrected L, as snow's clamp sees the corrected F in mode "F". With exclusive coupling
     the L of a PD particle is then replaced by its PD family's velocity gradient over the
     step (`_pd_velocity_gradient`): its stress works through the bonds on that rate, not
     on the grid's.
     Not in the thesis: what the boundaries (walls, colliders, clamps) take from the
     corrected grid velocity reaches every particle in their reach, and a PD particle whose
     stencil holds such a node takes the corrected grid velocity instead of its own (a grid
     node cannot hold a particle whose velocity is its own: the PD end of the patch-test bar
     slid off its wall, tests/verification/test_spb_coupled.py).

Pay for use: before the first conversion the step adds only the stress-chunk work and one
scalar grid field; the PD halo, bonds, the re-transfer grid field and the PD time-step bound
exist only once PD particles do (`pd_global` > 0, agreed by all ranks).

Restrictions (scene errors, `materials.failure.failure_scene_problems`): MLS transfer (the
re-transfer recomputes C, and C is the velocity gradient only for MLS) and the explicit
integrator. Deformation modes "F" and "L" (shock, j2 and elastic materials in one scene); eq.
6.10 divides tau by det F, or by the material's own J where it carries no F.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numba import njit

from ..errors import SceneError
from ..kernels.shape import stencil_base, weights
from ..kernels.transfer import SCATTER_FORCES
from ..materials.failure import SPB_FIELDS, failure_scene_problems, pd_moduli, pd_stress
from ..parallel.exchange import exchange_rows, pack_rows, row_dtype, unpack_rows
from ..parallel.pd_halo import TAG_PD_BONDS, PDHalo, align_rows, redistribute_segments
from ..state import VECTOR
from .bonds import Bonds
from .clamp import LINEAR_INFLUENCE, NO_FACES, clamp_parameters, sticky_faces
from .correspondence import (correspondence_force_state, correspondence_forces,
                             correspondence_kinematics, correspondence_rate)
from .energy_failure import WORK_STATE, critical_bond_energy, energy_failure
from .extension import CheckpointedBonds
from .families import (family_radius, find_families, full_family_sum, half_bonds_per_particle,
                       periodic_images, shift_into_box)
from .grid_energy import ENERGIES, ENERGY_HISTORY, FLAGGED_PARTICLES, grid_energy_release
from .load import add_bond_load, bond_cost
from .moduli import equivalent_micromodulus, pmb_micromodulus

log = logging.getLogger(__name__)

class SPBExtension(CheckpointedBonds):
    """SPB-MPM state of one rank (module docstring)."""

    grid_scattered = ("spb_energy",)
    output_fields = ("model", "damage", "EE")

    def __init__(self, sim):
        self.sim = sim
        self.dim = sim.dim
        self.groups = [g for g, m in enumerate(sim.materials) if getattr(m, "failure", None)]
        self.index = {g: k for k, g in enumerate(self.groups)}
        mats = [sim.materials[g] for g in self.groups]
        self.material = mats[0]          # names the bonds' checkpoint folder
        specs = [m.failure for m in mats]
        # parse_scene reports these already; a scene built in code meets them here.
        problems = failure_scene_problems(sim.materials, sim.scene.transfer,
                                          sim.scene.integrator, sim.scene.periods(),
                                          sim.dx / sim.scene.particles_per_cell)
        if problems:
            raise SceneError([f"{sim.scene.path}: {key}: {what}" for key, what in problems])
        f0 = specs[0]
        self.coupling = f0["coupling"]
        self.exclusive = self.coupling == "exclusive"
        self.failure = f0["bond_failure"]
        self.linear_influence = f0["influence"] == "linear"
        self.spacing = sim.dx / sim.scene.particles_per_cell
        self.delta = f0["horizon"] * self.spacing
        self.l0 = self.delta
        self.radius = family_radius(self.delta, self.spacing, True)   # PA-HHB
        self.s_reach = f0["max_bond_stretch"]
        self.s0 = min(f0["critical_stretch"], self.s_reach) if self.failure == "stretch" \
            else self.s_reach
        self.skin = self.spacing
        # The clamp's ghost bonds (clamp.py) at the sticky domain walls.
        self.clamp_faces = sticky_faces(sim.scene) if f0["clamp"] == "sticky_walls" \
            else NO_FACES
        self.clamp = clamp_parameters(self.delta, self.spacing,
                                      LINEAR_INFLUENCE if self.linear_influence else 0, True)
        self.energy_code = np.array([ENERGIES.index(s["energy"]) for s in specs])
        # eq. 6.10 divides tau by det F, or by the material's own volume ratio J where it
        # carries no F (the impact models in mode "L").
        self.volume = ["F" if m.deformation == "F" else "J" for m in mats]
        self.E = np.array([m.params["E"] for m in mats], dtype=np.float64)
        self.nu = np.array([m.params["nu"] for m in mats], dtype=np.float64)
        self.G_EE = np.array([s["grid_energy"] for s in specs], dtype=np.float64)
        self.Wc = np.array([critical_bond_energy(self.dim, s["bond_energy"], self.delta)
                            for s in specs], dtype=np.float64)
        # Zero-energy-mode control: G = stabilization * c, c the PMB micromodulus of the
        # material's bulk modulus (correspondence.py); one G per scene (a bond between two
        # materials must see the same G at both ends): the smallest.
        self.G = min(s["stabilization"] * pmb_micromodulus(
            self.dim, pd_moduli(self.dim, m)[0], self.delta) for s, m in zip(specs, mats))
        self.dt_pd = min(self._pd_time_step(m) for m in mats)
        self.pd_global = 0          # PD particles on all ranks
        self.need_x0 = True
        # Verification only (the patch test, "G_EE = 0"): convert every SPB particle at the
        # next step, which a scene cannot ask for (grid_energy must be > 0).
        self.convert_all = False
        self.checked = False        # this step's G_i reached a G_EE somewhere (all ranks)
        self.held = 0               # PD particles held by a boundary in the last step
        self.bonds: Bonds | None = None
        self.bond_ids = np.empty(0, np.int64)
        self.halo: PDHalo | None = None
        self._flag_out = np.empty(0, np.int64)
        self.converted = 0          # conversions on all ranks, all steps
        self.broken = 0             # half-bonds broken on this rank
        self.flag_margin = math.inf     # smallest |G_i - G_EE| / G_EE seen (this rank)
        self.bond_margin = math.inf     # smallest |W - beta W_c| / (beta W_c) (this rank)
        self.halo_builds = 0
        self.inverted = 0           # PD particle-steps with an inverted family (this rank)
        # SPB materials of deformation mode "L" (shock, j2): their PD particles' state
        # advances with the PD family's velocity gradient (`_pd_velocity_gradient`).
        self.mode_l_groups = [g for g, m in zip(self.groups, mats) if m.deformation == "L"]

    # -- time step ----------------------------------------------------------------------------
    def _pd_time_step(self, material) -> float:
        """0.8 sqrt(2 rho / sum_q V c w / |X|) over a full lattice family (Silling & Askari;
        moduli.py), with c the micromodulus of the material's P-wave modulus plus the
        stabilization's."""
        c = equivalent_micromodulus(self.dim, *pd_moduli(self.dim, material),
                                    self.delta) + self.G
        # sum_q V_q beta_q omega_q / |X_q| (partial volumes beta); with omega = |X| / delta
        # that is sum_q V_q beta_q / delta.
        if self.linear_influence:
            k = full_family_sum(self.dim, self.spacing, self.delta) / self.delta
        else:
            k = full_family_sum(self.dim, self.spacing, self.delta, power=-1)
        return 0.8 * math.sqrt(2.0 * material.density / (c * k))

    def dt_limit(self, sim) -> float:
        """The PD bound once PD particles exist: alone (exclusive coupling) or combined with
        the MPM wave-speed bound as 1/dt^2 = 1/dt_cfl^2 + 1/dt_pd^2 (additive: both
        stiffnesses act on the same particles)."""
        if not self.pd_global:
            return math.inf
        if self.exclusive:
            return self.dt_pd
        dt_cfl = sim.scene.cfl * sim.dx / sim.max_wave_speed()
        return 1.0 / math.sqrt(1.0 / dt_cfl ** 2 + 1.0 / self.dt_pd ** 2)

    @staticmethod
    def _report_undefined_stress(sim, material, fields, rows, F, tau) -> None:
        """A PD stress that divides by zero (snow's F_E = F^PD F_P^-1 with a singular F_P: a
        state already blown up) stops the run through the health check, on every rank alike:
        the particles it cannot be computed for get a non-finite velocity (the next step's
        check reports their ids, step and time) and stress 0 for the rest of this step, the
        others their stress, and the material's failure note names the cause (it was a
        ZeroDivisionError traceback). Each row is evaluated alone by the material's own
        kernel, so "cannot be computed" is exactly where it divides by zero; this runs once,
        as the run stops."""
        bad = np.zeros(len(rows), dtype=bool)
        for i in range(len(rows)):
            one = slice(i, i + 1)
            try:
                pd_stress(material, {k: v[one] for k, v in fields.items()}, F[one], tau[one])
            except ZeroDivisionError:
                bad[i] = True
        if not bad.any():
            return
        tau[bad] = 0.0
        sim.particles["v"][rows[bad]] = np.nan
        material.failures.append("the peridynamic stress is undefined (a singular plastic "
                                 "deformation F_P, det F_P = 0)")

    # -- P2G: eq. 6.10 ------------------------------------------------------------------------
    def stress_chunk(self, sim, g: int, start: int, stop: int, tau: np.ndarray, dt: float):
        k = self.index.get(g)
        if k is None:
            return
        p = sim.particles
        if self.need_x0:             # the reference configuration: positions at t = 0
            x0 = p["x0"][start:stop]
            unset = np.isnan(x0[:, 0])
            x0[unset] = p["x"][start:stop][unset]
        ENERGY_HISTORY[self.dim](p["x"][start:stop], p["mass"][start:stop], tau,
                                 p[self.volume[k]][start:stop], p["EE"][start:stop],
                                 self.energy_code[k],
                                 self.E[k], self.nu[k], sim._static_order, sim.dx,
                                 sim.domain_lo, sim.grid.origin, sim.grid["spb_energy"])
        if self.exclusive and self.pd_global:
            pd = p["model"][start:stop] == 1
            tau[pd] = 0.0

    # -- after G2P, before the state update: Alg. 3 ---------------------------------------------
    def before_state(self, sim, dt: float) -> None:
        self.need_x0 = False
        with sim.phase("spb_convert"):
            new_rows = self._convert(sim, dt)
            n_new = int(sim.domain.sum(len(new_rows))) if self.checked else 0
        self.converted += n_new
        self.pd_global += n_new
        if not self.pd_global:
            return
        with sim.phase("pd"):
            pd_rows = np.flatnonzero(sim.particles["model"] == 1)
            self._sync_bonds(sim, pd_rows, new_rows, n_new)
            dv = self._evolve(sim, pd_rows, dt)
        with sim.phase("spb_retransfer"):
            self._retransfer(sim, pd_rows, dv, dt)
        if self.mode_l_groups and self.exclusive:
            with sim.phase("pd"):
                self._pd_velocity_gradient(sim, pd_rows, dt)

    def _convert(self, sim, dt: float) -> np.ndarray:
        """Rows of MPM particles of SPB materials in a cell with a flagged corner (eq. 6.10,
        6.3.1); marks them PD."""
        p, grid = sim.particles, sim.grid
        # G_i on the owners (e and m complete there after the ghost sum), then to the ghost
        # copies, so every rank flags from the owners' values.
        top = grid_energy_release(grid["spb_energy"], grid["mass"], self.l0,
                                  grid["spb_energy"])
        # Nothing can convert unless some G_i reaches the smallest G_EE on some rank (one
        # reduction; before the first conversion the step ends here).
        self.checked = self.convert_all or sim.domain.max(top) >= self.G_EE.min()
        if not self.checked:
            return np.empty(0, np.int64)
        sim.domain.fill_ghosts(grid, "spb_energy")
        found = []
        for k, g in enumerate(self.groups):
            start, stop = sim.group_slices[g]
            if stop <= start:
                continue
            if self.convert_all:
                rows = np.arange(start, stop, dtype=np.int64)
                found.append(rows[p["model"][start:stop] == 0])
                continue
            if len(self._flag_out) < stop - start:
                self._flag_out = np.empty(p.capacity, np.int64)
            count, margin = FLAGGED_PARTICLES[self.dim](
                p["x"], p["v"], dt, np.arange(start, stop, dtype=np.int64), p["model"],
                grid["spb_energy"], self.G_EE[k], sim.domain_lo, sim.dx, grid.origin,
                self._flag_out)
            self.flag_margin = min(self.flag_margin, margin)
            found.append(self._flag_out[:count].copy())
        rows = np.concatenate(found) if found else np.empty(0, np.int64)
        p["model"][rows] = 1
        self.convert_all = False
        return rows

    # -- bonds ----------------------------------------------------------------------------------
    def _state_names(self):
        return WORK_STATE if self.failure == "work" else ()

    def _sync_bonds(self, sim, pd_rows, new_rows, n_new) -> None:
        """Bond rows follow the PD rows (by id) after sorts, migration and rebalancing; the
        new PD particles get their bonds; the PD halo is rebuilt when anything changed (a
        particle wrapped across a periodic face moved by a period: the halo is stale)."""
        p, domain = sim.particles, sim.domain
        ids = p["id"][pd_rows]
        new_ids = p["id"][new_rows]
        old_ids = ids[~np.isin(ids, new_ids)] if len(new_ids) else ids
        if self.bonds is None:
            self.bonds = Bonds.empty(0, self._state_names())
        moved = domain.any(not np.array_equal(old_ids, self.bond_ids))
        if moved:
            local = len(old_ids) == len(self.bond_ids) and \
                np.array_equal(np.sort(old_ids), np.sort(self.bond_ids))
            if domain.min(float(local)) > 0:
                align_rows(self.bonds, self.bond_ids, old_ids)
            else:
                redistribute_segments(domain, self.bonds, self.bond_ids, old_ids)
            self.bond_ids = old_ids.copy()
        if len(new_ids):
            self.bonds.append(np.zeros(len(new_ids), np.int64),
                              {"partner": np.empty(0, np.int64), "weight": np.empty(0),
                               "status": np.empty(0, np.int8)})
        if len(new_ids):
            align_rows(self.bonds, np.concatenate([self.bond_ids, new_ids]), ids)
            self.bond_ids = ids.copy()
        if n_new:
            self._new_bonds(sim, pd_rows, np.isin(ids, new_ids))
        x = p["x"][pd_rows]
        if n_new or moved or self.halo is None or self.halo.stale(x):
            self._rebuild_halo(sim, pd_rows)
        else:
            n = len(pd_rows)
            self.pts_x[:n] = x
            self.halo.refresh({"x": x}, {"x": self.pts_x[n:]})

    def _new_bonds(self, sim, pd_rows, is_new) -> None:
        """Half-bonds of the new PD particles (module docstring, 2.). Collective."""
        p, domain = sim.particles, sim.domain
        rows_new = pd_rows[is_new]
        mine = {"id": p["id"][rows_new], "x0": p["x0"][rows_new], "x": p["x"][rows_new]}
        every = domain.allgather(mine)
        others = [r for r in range(domain.size) if r != domain.rank]
        g_id = np.concatenate([every[r]["id"] for r in others] or [np.empty(0, np.int64)])
        g_x0 = np.concatenate([every[r]["x0"] for r in others] or [np.empty((0, self.dim))])
        g_x = np.concatenate([every[r]["x"] for r in others] or [np.empty((0, self.dim))])
        g_rank = np.concatenate([np.full(len(every[r]["id"]), r) for r in others]
                                or [np.empty(0, np.int64)])
        # Along periodic axes every reference position is brought into the box and the
        # points near its faces get images, so bonds reach across a face; the current
        # positions move with the same shifts.
        x0_mine, x_mine = p["x0"][pd_rows], p["x"][pd_rows]
        period = sim.domain.period_lengths()
        lo = np.asarray(sim.domain_lo, np.float64)
        periodic = bool(period.any())
        if periodic:
            shift = shift_into_box(x0_mine, lo, period)
            x0_mine, x_mine = x0_mine + shift, x_mine + shift
            shift = shift_into_box(g_x0, lo, period)
            g_x0, g_x = g_x0 + shift, g_x + shift
        # My PD particles within the search radius of some new particle (reference cells of
        # the radius: a neighbour is at most one cell away), or of an image of one.
        new_x0 = np.concatenate([x0_mine[is_new], g_x0])
        if periodic and len(new_x0):
            src, img = periodic_images(new_x0, lo, period, self.radius)
            new_x0 = np.concatenate([new_x0, new_x0[src] + img])
        near = _near_cells(x0_mine, new_x0, self.radius) if len(new_x0) else \
            np.zeros(len(pd_rows), bool)
        sel = np.flatnonzero(near | is_new)
        pts_x0 = np.concatenate([x0_mine[sel], g_x0])
        pts_x = np.concatenate([x_mine[sel], g_x])
        pts_id = np.concatenate([p["id"][pd_rows[sel]], g_id])
        pts_new = np.concatenate([is_new[sel], np.ones(len(g_id), bool)])
        n_sel, n_pts = len(sel), len(pts_id)
        src = np.empty(0, np.int64)
        if periodic:
            src, img = periodic_images(pts_x0, lo, period, self.radius)
            pts_x0 = np.concatenate([pts_x0, pts_x0[src] + img])
            pts_x = np.concatenate([pts_x, pts_x[src] + img])
        fam = find_families(pts_x0, np.concatenate([pts_id, pts_id[src]]), n_sel,
                            self.spacing, self.delta)
        b = fam.bonds
        owner = np.repeat(np.arange(n_sel), b.counts())
        slot = b.slot.astype(np.int64)
        # The point each bond reaches (an image's source) names its id, rank and newness.
        base = np.where(slot < n_pts, slot, src[np.maximum(slot - n_pts, 0)] if len(src)
                        else slot)
        keep = pts_new[owner] | pts_new[base]
        owner, slot, base, weight = owner[keep], slot[keep], base[keep], b.weight[keep]
        X = pts_x0[slot] - pts_x0[owner]
        Y = pts_x[slot] - pts_x[owner]
        xl = np.sqrt(np.sum(X * X, axis=1))
        yl = np.sqrt(np.sum(Y * Y, axis=1))
        if self.linear_influence:
            weight = weight * (xl / self.delta)
        status = ((yl - xl) / xl <= self.s_reach).astype(np.int8)
        rows = sel[owner]                          # bond rows (= index in pd_rows)
        # The far end of a bond from an existing PD particle of mine to another rank's new
        # particle: its owner does not see my particle, so it gets its half-bond from me.
        remote = (base >= n_sel) & ~pts_new[owner]
        records = {"target": pts_id[base[remote]], "partner": pts_id[owner[remote]],
                   "weight": weight[remote], "status": status[remote],
                   "rank": g_rank[base[remote] - n_sel]}
        local = base < n_sel
        partner = pts_id[base]
        got = _send_records(domain, records)
        pd_ids = p["id"][pd_rows]
        by_id = np.argsort(pd_ids, kind="stable")
        got_rows = by_id[np.searchsorted(pd_ids[by_id], got["target"])]
        self.bonds.merge(np.concatenate([rows, got_rows]),
                         np.concatenate([partner, got["partner"]]),
                         np.concatenate([weight, got["weight"]]),
                         np.concatenate([status, got["status"]]))
        self.new_local_pairs = int(local.sum())

    def _rebuild_halo(self, sim, pd_rows) -> None:
        p = sim.particles
        if self.halo is None:
            self.halo = PDHalo(sim.domain, self.radius * (1.0 + self.s_reach), self.skin)
        wc = self.Wc[np.searchsorted(np.array(self.groups), p["group"][pd_rows])]
        static = {"id": p["id"][pd_rows], "x0": p["x0"][pd_rows], "vol0": p["vol0"][pd_rows],
                  "x": p["x"][pd_rows], "wc": wc}
        halo = self.halo.build(static["x"], static)
        cat = lambda k: np.concatenate([static[k], halo[k]]).astype(static[k].dtype)  # noqa
        self.pts_ids, self.pts_x0, self.pts_vol = cat("id"), cat("x0"), cat("vol0")
        self.pts_x, self.pts_wc = cat("x"), cat("wc")
        self.bonds.resolve_slots(self.pts_ids, self.pts_x0, sim.domain.period_lengths())
        self.halo_builds += 1
        m, d = len(self.pts_x), self.dim
        self.F = np.zeros((m, d, d))
        self.Kinv = np.zeros((m, d, d))
        self.A = np.zeros((m, d, d))
        self.active = np.zeros(m)

    # -- PD evolution ---------------------------------------------------------------------------
    def _evolve(self, sim, pd_rows, dt: float) -> np.ndarray:
        """Alg. 3 lines 3-27 (corrected) on the PD particles at x^; returns v - v^."""
        p, b = sim.particles, self.bonds
        n = len(pd_rows)
        self.broken += correspondence_kinematics(
            self.pts_x, self.pts_x0, self.pts_vol, b.offsets, b.slot, b.status, b.weight,
            self.s0, n, self.F, self.Kinv, self.active, self.clamp_faces, self.clamp)
        tau = np.zeros((n, self.dim, self.dim))
        # Mode "L" (exclusive): the artificial viscosity of the PD stress from the PD family's
        # rate over this step's prediction x^n -> x^ (= x^n + dt v^), not from the grid's C^,
        # as the state update takes it (`_pd_velocity_gradient`): the same q does work on
        # the bonds and is taken from E.
        L_pd = self._family_rate(p["x"][pd_rows], p["v"][pd_rows], dt) \
            if self.mode_l_groups and self.exclusive else None
        for g in self.groups:
            # pd_rows ascend and each material's rows are one slice: its PD rows are too.
            a, e = np.searchsorted(pd_rows, sim.group_slices[g])
            if e > a:
                material = sim.materials[g]
                rows = pd_rows[a:e]
                # The material's own state (snow: Fp, Jp), not the SPB fields.
                fields = {name: p[name][rows] for name in material.fields
                          if name not in SPB_FIELDS}
                if "L" in p:            # the step's velocity gradient (artificial viscosity)
                    fields["L"] = p["L"][rows] if L_pd is None else L_pd[a:e]
                F = np.ascontiguousarray(self.F[a:e])
                try:
                    pd_stress(material, fields, F, tau[a:e])
                except ZeroDivisionError:
                    self._report_undefined_stress(sim, material, fields, rows, F, tau[a:e])
        correspondence_force_state(self.F, self.Kinv, tau, self.active, n, self.A)
        # An inverted PD family (det F^PD <= 0: a particle left with a few bonds that no
        # longer span the space) carries no PD stress, like a detached one, instead of
        # stopping the run: its MPM stress (additive) or its bonds' neighbours still act.
        inverted = ~np.isfinite(self.A[:n].reshape(n, self.dim * self.dim)).all(axis=1)
        if inverted.any():
            self.A[:n][inverted] = 0.0
            self.active[:n][inverted] = 0.0
            self.inverted += int(inverted.sum())
        fields = {"A": self.A, "F": self.F, "active": self.active}
        self.halo.refresh({k: a[:n] for k, a in fields.items()},
                          {k: a[n:] for k, a in fields.items()})
        f = np.empty((n, self.dim))
        correspondence_forces(self.pts_x, self.pts_x0, self.pts_vol, b.offsets, b.slot,
                              b.status, b.weight, self.A, self.F, self.active, self.G, n, f,
                              self.clamp_faces, self.clamp)
        dv = dt * f / p["mass"][pd_rows][:, None]
        p["v"][pd_rows] += dv
        p["x"][pd_rows] += dt * dv            # x^n + dt v^{n+1} (line 21 corrected)
        if self.failure != "stretch":
            state = [b.state[k] for k in WORK_STATE] if self.failure == "work" else \
                [np.empty(0)] * len(WORK_STATE)
            broken, margin = energy_failure(
                self.pts_x, self.pts_x0, b.offsets, b.slot, b.status, b.weight, self.A, n,
                self.pts_wc, self.delta, self.spacing, True, self.failure == "work", *state)
            self.broken += broken
            self.bond_margin = min(self.bond_margin, margin)
        bond_damage(b.offsets, b.status, b.weight, n, p["damage"], p["active_bonds"], pd_rows)
        return dv

    # -- transfer again -----------------------------------------------------------------------
    def _retransfer(self, sim, pd_rows, dv, dt: float) -> None:
        """"Transfer again" (module docstring, 4.)."""
        p, grid, domain = sim.particles, sim.grid, sim.domain
        for name in ("spb_dvelocity", "spb_reaction"):
            if name not in grid.kinds:
                grid.declare(name, VECTOR)
        dvel, reaction = grid["spb_dvelocity"], grid["spb_reaction"]
        dvel[...] = 0.0
        xn = p["x"][pd_rows] - dt * p["v"][pd_rows]
        impulse = p["mass"][pd_rows][:, None] * dv
        ok = np.isfinite(impulse).all(axis=1)   # NaN rows: the health check reports them
        SCATTER_FORCES[self.dim](np.ascontiguousarray(xn[ok]),
                                 np.ascontiguousarray(impulse[ok]), sim._static_order,
                                 sim.dx, sim.domain_lo, grid.origin, 1.0, dvel)
        domain.sum_ghosts_to_owners(grid, "spb_dvelocity")
        d = self.dim
        velocity, mass = grid["velocity"].reshape(-1, d), grid["mass"].reshape(-1)
        # dvel: the momentum correction -> the free velocity correction; reaction: the
        # corrected velocity, then the boundaries act on it.
        grid_correction(velocity, mass, dvel.reshape(-1, d), reaction.reshape(-1, d))
        sim.apply_grid_boundaries(reaction, dt)
        # dvel: corrected - v_i; reaction: what the boundaries took from the correction.
        boundary_reaction(velocity, dvel.reshape(-1, d), reaction.reshape(-1, d))
        domain.fill_ghosts(grid, "spb_dvelocity", "spb_reaction")
        # PD particles next to a constrained node (a wall, collider or clamp took part of the
        # correction there) take the corrected grid velocity like MPM particles: a grid node
        # cannot hold a particle whose velocity is its own, and the one-sided bond force of a
        # family cut by the boundary drifts it off the wall otherwise (the fixed end of the
        # patch-test bar slid away: tests/verification/test_spb_coupled.py).
        xn = np.ascontiguousarray(p["x"][pd_rows] - dt * p["v"][pd_rows])
        near = np.zeros(len(pd_rows), np.int8)
        stencil_touches(xn, reaction.reshape(-1, self.dim), np.array(reaction.shape[:-1]),
                        grid.origin, sim.domain_lo, sim.dx, sim._static_order, near)
        held = pd_rows[near == 1]
        p["v"][held] -= dv[near == 1]
        p["x"][held] -= dt * dv[near == 1]
        # Mode "F": F already holds (I + dt C^) F^n and is corrected; mode "L": the stored
        # velocity gradient L = C^ takes the increment of C, the state update comes after.
        mode_l = sim.deformation == "L"
        target = p["L"] if mode_l else p["F"]
        for g in sim._on_grid:
            start, stop = sim.group_slices[g]
            if stop > start:
                REGATHER[self.dim](p["x"][start:stop], p["v"][start:stop], p["C"][start:stop],
                                   target[start:stop], mode_l, sim.dinv_factor, sim.dx,
                                   sim.domain_lo, grid.origin, dt, sim._static_order, dvel,
                                   reaction)
        if len(held):
            # They took the boundaries' reaction above; now the rest of the correction.
            np.subtract(dvel, reaction, out=reaction)
            gather_increment(p["x"], p["v"], held, dt, reaction.reshape(-1, self.dim),
                             np.array(reaction.shape[:-1]), grid.origin, sim.domain_lo,
                             sim.dx, sim._static_order)
        self.held = len(held)
        # Snow's clamp and the mode-L state updates run next (Simulation.update_states) on
        # the corrected F or L.

    def _pd_velocity_gradient(self, sim, pd_rows, dt: float) -> None:
        """The velocity gradient L that the state update of a mode-"L" material (shock, j2)
        reads, for its PD particles: the rate of their PD deformation, L^PD = (F^PD(x^{n+1})
        F^PD(x^n)^-1 - I) / dt over the intact bonds (`correspondence_rate`), with x^n =
        x^{n+1} - dt v^{n+1} (every PD particle moved by its final velocity, the held ones
        too). The PD particle's stress acts through its bonds, whose force works on exactly
        this rate (sum_p f_p . v_p = -sum_p V_p P_p : F_dot_p, 003 eq. 4.7 / 6.6 summed by
        parts), so J, F_E and the internal energy E (003 eq. 7.3: de = dt sym(L) : sigma,
        with the EOS work of eq. 7.4) follow the deformation the bonds resist and E gains
        the work they do. 003 §7.2.2 evaluates sigma^PD with "the strain tensor ... from
        F_p^PD in the state-based PD"; the grid's C of a PD particle (what G2P and the
        re-transfer left in L) is not its deformation under exclusive coupling: nothing on
        the grid resists it, and a converted shock block on a floor was compressed there to
        J = 0.47 while its PD families kept det F^PD ~ 1, its pressure and E growing 30 times
        past the impact's kinetic energy. Exclusive coupling only: under additive coupling
        (Alg. 3 as printed) the particle's stress works twice, on the grid's L through P2G
        and on L^PD through its bonds; no one L makes E that work (the sum of both rates,
        tried, advances J twice for one volume change and blew up), so it keeps the grid's
        L as before."""
        p = sim.particles
        L = self._family_rate(p["x"][pd_rows], p["v"][pd_rows], dt)
        for g in self.mode_l_groups:
            a, e = np.searchsorted(pd_rows, sim.group_slices[g])
            if e > a:
                p["L"][pd_rows[a:e]] = L[a:e]

    def _family_rate(self, x, v, dt: float) -> np.ndarray:
        """`correspondence_rate` of the owned PD points (rows of x, v: my PD rows) moved by
        dt v to x over the bonds as they are now (n, d, d). Collective (the halo's x, v)."""
        n = len(x)
        x = np.ascontiguousarray(x)
        v = np.ascontiguousarray(v)
        halo = self.halo.refresh({"x": x, "v": v})
        x_new = np.concatenate([x, halo["x"]])
        x_old = x_new - dt * np.concatenate([v, halo["v"]])
        b = self.bonds
        L = np.zeros((n, self.dim, self.dim))
        correspondence_rate(x_new, x_old, self.pts_x0, self.pts_vol, b.offsets, b.slot,
                            b.status, b.weight, self.active, n, dt, self.clamp_faces,
                            self.clamp, L)
        return L

    # -- checkpoints ----------------------------------------------------------------------------
    # Bonds checkpoint through pd/extension.CheckpointedBonds (beside the particle checkpoint,
    # in pd_bonds_<first SPB material>/); EE_p, x0, model, damage and active_bonds are particle
    # fields.
    def checkpoint_ids(self) -> np.ndarray:
        return self.sim.particles["id"][self.sim.particles["model"] == 1].copy()

    def restore(self, particle_checkpoint) -> None:
        """Bonds of the checkpoint (collective); the PD count follows from the model field."""
        super().restore(particle_checkpoint)
        self.pd_global = int(self.sim.domain.sum(int(np.sum(self.sim.particles["model"] == 1))))
        self.converted = self.pd_global
        self.need_x0 = False
        if self.bonds is not None and self.failure == "work":
            for name in WORK_STATE:
                self.bonds.add_state(name)

    # -- load balance -------------------------------------------------------------------------
    def add_load(self, sim, weights: np.ndarray) -> None:
        """`Simulation.load_weights`: a PD particle costs c_b (the correspondence model's,
        pd/load.py) times its active half-bonds more, the particle field "active_bonds" that
        `bond_damage` counts from the bond rows after each PD step (conversions and their
        bonds come before it in the step, so the count is current whenever the runner
        rebalances): it travels with the particle through migration, so the weight is the
        same on every rank count although the bond rows are realigned only at the next step.
        A PD particle whose neighbours are not PD yet weighs the bonds it has. Before any
        conversion every weight stays 1 unit: the decomposition of the MPM scene (the units
        are 64 = 2^6, so the bisection's quantiles and the imbalance are the count's,
        bitwise)."""
        p = sim.particles
        rows = np.flatnonzero(p["model"] == 1)
        if not len(rows):
            return
        add_bond_load(weights, rows, p["active_bonds"][rows], sim.particle_weight,
                      bond_cost(self.dim, "correspondence"),
                      half_bonds_per_particle(self.dim, self.delta / self.spacing, True))

    # -- diagnostics --------------------------------------------------------------------------
    def margins(self, domain) -> dict:
        """Smallest relative distance to the conversion and bond thresholds, all ranks."""
        return {"flag": domain.min(self.flag_margin), "bond": domain.min(self.bond_margin)}


def _near_cells(x, targets, h) -> np.ndarray:
    """Mask of the points ``x`` within one cell (side h) of a cell holding a target."""
    dim = x.shape[1]
    lo = np.minimum(x.min(axis=0), targets.min(axis=0)) if len(x) else targets.min(axis=0)
    cx = np.floor((x - lo) / h).astype(np.int64)
    ct = np.floor((targets - lo) / h).astype(np.int64)
    span = np.maximum(cx.max(axis=0) if len(x) else 0, ct.max(axis=0)) + 3

    def key(c):
        k = np.zeros(len(c), np.int64)
        for a in range(dim):
            k = k * span[a] + (c[:, a] + 1)
        return k

    offsets = np.stack(np.meshgrid(*[np.arange(-1, 2)] * dim, indexing="ij"), -1)
    hit = np.unique(np.concatenate([key(ct + o) for o in offsets.reshape(-1, dim)]))
    return np.isin(key(cx), hit)


def _send_records(domain, records) -> dict:
    """Half-bond records to the ranks that own their ``target`` particle. Collective."""
    order = np.argsort(records["rank"], kind="stable")
    send_counts = np.bincount(records["rank"][order], minlength=domain.size).astype(np.int64)
    recv_counts = np.empty(domain.size, np.int64)
    domain.comm.Alltoall(send_counts, recv_counts)
    rows = {k: np.ascontiguousarray(v) for k, v in records.items() if k != "rank"}
    ranks = np.arange(domain.size)
    recv = exchange_rows(domain.comm, pack_rows(rows, order, row_dtype(rows)), ranks,
                         send_counts, ranks, recv_counts, TAG_PD_BONDS)
    return {k: np.ascontiguousarray(v) for k, v in unpack_rows(recv).items()}


@njit(cache=True, error_model="numpy")
def bond_damage(offsets, status, weight, n, damage, active, rows):
    """damage[rows[p]] = 1 - sum_intact w / sum_all w over the bonds made so far (0 without
    bonds: a PD particle whose neighbours are not PD yet is not damaged; 003 eq. 4.8 with
    the partial volumes as weights). Bonds that started broken count. In the same pass
    active[rows[p]] = the intact half-bonds (the load-balance weight,
    `SPBExtension.add_load`)."""
    for p in range(n):
        total = 0.0
        intact = 0.0
        count = 0
        for b in range(offsets[p], offsets[p + 1]):
            total += weight[b]
            if status[b] != 0:
                intact += weight[b]
                count += 1
        damage[rows[p]] = 1.0 - intact / total if total > 0.0 else 0.0
        active[rows[p]] = count


@njit(cache=True)
def regather_2d(x, v, C, F, add_to_L, dinv_factor, dx, domain_lo, origin, dt, order, dvel,
                reaction):
    """The re-transfer's G2P for MLS in 2D (module docstring, 4.): particles with a
    corrected node in their stencil get C += D^-1 sum_i w dv_i (x_i - x^n)^T and F <-
    (I + dt C_new)(I + dt C_old)^-1 F, x^n = x - dt v (``add_to_L``: F is the stored
    velocity gradient L of mode "L" and takes the same increment as C); the boundaries' reaction r_i to the
    correction reaches the velocity, v += sum_i w r_i, and the position, x += dt sum_i w r_i.
    In place."""
    order = len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    lo0, lo1 = domain_lo[0], domain_lo[1]
    o0, o1 = origin[0], origin[1]
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - dt * v[p, 0] - lo0) * inv_dx
        xi1 = (x[p, 1] - dt * v[p, 1] - lo1) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        l0, l1 = b0 - o0, b1 - o1
        touched = False
        for i in range(s):
            for j in range(s):
                if dvel[l0 + i, l1 + j, 0] != 0.0 or dvel[l0 + i, l1 + j, 1] != 0.0 or \
                        reaction[l0 + i, l1 + j, 0] != 0.0 or reaction[l0 + i, l1 + j, 1] != 0.0:
                    touched = True
        if not touched:
            continue
        w0, _ = weights(xi0, b0, order, inv_dx)
        w1, _ = weights(xi1, b1, order, inv_dx)
        e0, e1 = (b0 - xi0) * dx, (b1 - xi1) * dx
        c00 = c01 = c10 = c11 = 0.0
        r0 = r1 = 0.0
        for i in range(s):
            d0 = e0 + i * dx
            for j in range(s):
                d1 = e1 + j * dx
                wij = w0[i] * w1[j]
                u0 = wij * dvel[l0 + i, l1 + j, 0]
                u1 = wij * dvel[l0 + i, l1 + j, 1]
                c00 += u0 * d0
                c01 += u0 * d1
                c10 += u1 * d0
                c11 += u1 * d1
                r0 += wij * reaction[l0 + i, l1 + j, 0]
                r1 += wij * reaction[l0 + i, l1 + j, 1]
        v[p, 0] += r0
        v[p, 1] += r1
        x[p, 0] += dt * r0
        x[p, 1] += dt * r1
        if add_to_L:
            C[p, 0, 0] += dinv * c00
            C[p, 0, 1] += dinv * c01
            C[p, 1, 0] += dinv * c10
            C[p, 1, 1] += dinv * c11
            F[p, 0, 0] += dinv * c00
            F[p, 0, 1] += dinv * c01
            F[p, 1, 0] += dinv * c10
            F[p, 1, 1] += dinv * c11
            continue
        # M = (I + dt C_old)^-1
        a00, a01 = 1.0 + dt * C[p, 0, 0], dt * C[p, 0, 1]
        a10, a11 = dt * C[p, 1, 0], 1.0 + dt * C[p, 1, 1]
        idet = 1.0 / (a00 * a11 - a01 * a10)
        m00, m01, m10, m11 = a11 * idet, -a01 * idet, -a10 * idet, a00 * idet
        C[p, 0, 0] += dinv * c00
        C[p, 0, 1] += dinv * c01
        C[p, 1, 0] += dinv * c10
        C[p, 1, 1] += dinv * c11
        # N = (I + dt C_new) M
        b00, b01 = 1.0 + dt * C[p, 0, 0], dt * C[p, 0, 1]
        b10, b11 = dt * C[p, 1, 0], 1.0 + dt * C[p, 1, 1]
        n00 = b00 * m00 + b01 * m10
        n01 = b00 * m01 + b01 * m11
        n10 = b10 * m00 + b11 * m10
        n11 = b10 * m01 + b11 * m11
        f00, f01, f10, f11 = F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1]
        F[p, 0, 0] = n00 * f00 + n01 * f10
        F[p, 0, 1] = n00 * f01 + n01 * f11
        F[p, 1, 0] = n10 * f00 + n11 * f10
        F[p, 1, 1] = n10 * f01 + n11 * f11


@njit(cache=True)
def regather_3d(x, v, C, F, add_to_L, dinv_factor, dx, domain_lo, origin, dt, order, dvel,
                reaction):
    """3D `regather_2d` (small arrays allocated once per call, not per particle)."""
    order = len(order)
    inv_dx = 1.0 / dx
    dinv = dinv_factor * inv_dx * inv_dx
    s = order + 1
    dC = np.empty((3, 3))
    A = np.empty((3, 3))
    M = np.empty((3, 3))
    N = np.empty((3, 3))
    Fp = np.empty((3, 3))
    for p in range(x.shape[0]):
        xi0 = (x[p, 0] - dt * v[p, 0] - domain_lo[0]) * inv_dx
        xi1 = (x[p, 1] - dt * v[p, 1] - domain_lo[1]) * inv_dx
        xi2 = (x[p, 2] - dt * v[p, 2] - domain_lo[2]) * inv_dx
        b0 = stencil_base(xi0, order)
        b1 = stencil_base(xi1, order)
        b2 = stencil_base(xi2, order)
        l0, l1, l2 = b0 - origin[0], b1 - origin[1], b2 - origin[2]
        touched = False
        for i in range(s):
            for j in range(s):
                for k in range(s):
                    for a in range(3):
                        if dvel[l0 + i, l1 + j, l2 + k, a] != 0.0 or \
                                reaction[l0 + i, l1 + j, l2 + k, a] != 0.0:
                            touched = True
        if not touched:
            continue
        w0, _ = weights(xi0, b0, order, inv_dx)
        w1, _ = weights(xi1, b1, order, inv_dx)
        w2, _ = weights(xi2, b2, order, inv_dx)
        e0, e1, e2 = (b0 - xi0) * dx, (b1 - xi1) * dx, (b2 - xi2) * dx
        dC[:, :] = 0.0
        r0 = r1 = r2 = 0.0
        for i in range(s):
            for j in range(s):
                for k in range(s):
                    w = w0[i] * w1[j] * w2[k]
                    d = (e0 + i * dx, e1 + j * dx, e2 + k * dx)
                    for a in range(3):
                        u = w * dvel[l0 + i, l1 + j, l2 + k, a]
                        for c in range(3):
                            dC[a, c] += u * d[c]
                    r0 += w * reaction[l0 + i, l1 + j, l2 + k, 0]
                    r1 += w * reaction[l0 + i, l1 + j, l2 + k, 1]
                    r2 += w * reaction[l0 + i, l1 + j, l2 + k, 2]
        v[p, 0] += r0
        v[p, 1] += r1
        v[p, 2] += r2
        x[p, 0] += dt * r0
        x[p, 1] += dt * r1
        x[p, 2] += dt * r2
        if add_to_L:
            for a in range(3):
                for c in range(3):
                    C[p, a, c] += dinv * dC[a, c]
                    F[p, a, c] += dinv * dC[a, c]
            continue
        for a in range(3):
            for c in range(3):
                A[a, c] = (1.0 if a == c else 0.0) + dt * C[p, a, c]
        _inverse3(A, M)
        for a in range(3):
            for c in range(3):
                C[p, a, c] += dinv * dC[a, c]
        for a in range(3):
            for c in range(3):
                s_ = 0.0
                for k in range(3):
                    s_ += ((1.0 if a == k else 0.0) + dt * C[p, a, k]) * M[k, c]
                N[a, c] = s_
        for a in range(3):
            for c in range(3):
                Fp[a, c] = F[p, a, c]
        for a in range(3):
            for c in range(3):
                s_ = 0.0
                for k in range(3):
                    s_ += N[a, k] * Fp[k, c]
                F[p, a, c] = s_


@njit(cache=True)
def _inverse3(A, out):
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    inv = 1.0 / (A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02)
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * inv
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * inv
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * inv
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * inv
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * inv
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * inv


REGATHER = {2: regather_2d, 3: regather_3d}


@njit(cache=True)
def grid_correction(velocity, mass, dmom, corrected):
    """dmom <- dmom / m (the free velocity correction), corrected = v + it; (nodes, d)."""
    for i in range(mass.shape[0]):
        for a in range(velocity.shape[1]):
            dv = dmom[i, a] / mass[i] if mass[i] > 0.0 else 0.0
            dmom[i, a] = dv
            corrected[i, a] = velocity[i, a] + dv


@njit(cache=True)
def boundary_reaction(velocity, dfree, corrected):
    """After the boundaries acted on ``corrected``: dfree <- corrected - v (the correction
    the particles take) and corrected <- corrected - (v + the free correction) (the part the
    boundaries took)."""
    for i in range(velocity.shape[0]):
        for a in range(velocity.shape[1]):
            c = corrected[i, a]
            free = velocity[i, a] + dfree[i, a]
            dfree[i, a] = c - velocity[i, a]
            corrected[i, a] = c - free


@njit(cache=True, inline="always")
def _node(l, shape, dim):
    """Row of node ``l`` (block-local indices) in a field flattened to (nodes, d)."""
    k = l[0]
    for a in range(1, dim):
        k = k * shape[a] + l[a]
    return k


@njit(cache=True)
def stencil_touches(xn, field, shape, origin, domain_lo, dx, order, out):
    """out[p] = 1 when a node of p's stencil at xn[p] has a nonzero ``field`` (nodes, d)."""
    order = len(order)
    dim = xn.shape[1]
    s = order + 1
    base = np.empty(dim, np.int64)
    l = np.empty(dim, np.int64)
    for p in range(xn.shape[0]):
        for a in range(dim):
            base[a] = stencil_base((xn[p, a] - domain_lo[a]) / dx, order) - origin[a]
        for corner in range(s ** dim):
            c = corner
            for a in range(dim):
                l[a] = base[a] + c % s
                c //= s
            k = _node(l, shape, dim)
            for a in range(dim):
                if field[k, a] != 0.0:
                    out[p] = 1


@njit(cache=True)
def gather_increment(x, v, rows, dt, field, shape, origin, domain_lo, dx, order):
    """v += sum_i w_ip field_i, x += dt (the same) for ``rows``, weights at x^n = x - dt v."""
    order = len(order)
    dim = x.shape[1]
    s = order + 1
    inv_dx = 1.0 / dx
    base = np.empty(dim, np.int64)
    l = np.empty(dim, np.int64)
    w = np.empty((dim, 4))
    acc = np.empty(dim)
    for r in range(rows.shape[0]):
        p = rows[r]
        for a in range(dim):
            xi = (x[p, a] - dt * v[p, a] - domain_lo[a]) * inv_dx
            b = stencil_base(xi, order)
            wa, _ = weights(xi, b, order, inv_dx)
            for k in range(4):
                w[a, k] = wa[k]
            base[a] = b - origin[a]
        acc[:] = 0.0
        for corner in range(s ** dim):
            c = corner
            wt = 1.0
            for a in range(dim):
                j = c % s
                l[a] = base[a] + j
                wt *= w[a, j]
                c //= s
            k = _node(l, shape, dim)
            for a in range(dim):
                acc[a] += wt * field[k, a]
        for a in range(dim):
            v[p, a] += acc[a]
            x[p, a] += dt * acc[a]

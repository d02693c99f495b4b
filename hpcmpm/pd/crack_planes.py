"""Crack planes (003 §5.4 as corrected by the issue): bond failure that cuts cracks instead of
scattering broken bonds, and the two-time integration of the particles on a crack.

Each step, before the model's own pass (which then only applies ``max_bond_stretch``):

1. p_inactive per grid cell: the broken fraction of the half-bonds of the PD particles in the
   cell (cell of the current position, the scene's grid spacing). Only cells holding a broken
   bond have p_inactive > 0: their keys are gathered from every rank and their (broken, total)
   counts summed over ranks (integers: exact in any order), so every rank holds the same
   table and can look up any particle, halo rows included.
2. Failure (eq. 5.21 divides by |X| twice; the issue's form): a bond breaks when

       l = (s - e_p) / (1 + p_bar) > l_threshold,      s = |Y|/|X| - 1,

   e_p the bond's plastic stretch (bond_energy with ``plastic_yield``; else 0) and p_bar the
   mean of the two ends' cell values, so both ends decide the same from bitwise equal inputs.
3. Planes: the particles with a bond broken in step 2 are gathered from all ranks and sorted
   by id (every rank then builds identical planes, independent of the rank count). Per cell,
   a plane through the mean current position of those particles, normal along the bond with
   the largest l (ties: the lowest particle id). Every intact bond whose current segment
   crosses a plane (its ends on opposite sides) with its midpoint within max(dx, delta) of
   the plane's point (distance in the plane) breaks, on every rank that owns an end.

Two-time integration (``integration = "grid"``): particles with a broken bond (damage > 0)
move by their own PD force, v <- v^n + dt (f/m + g), x <- x^n + dt v, instead of the grid
velocity, the domain walls, the colliders and the prescribed sets acting on them per particle
(boundary.py, as on off-grid PD bodies). Their force still reaches
the grid: they are still scattered with their mass and momentum, and the grid near them must
see the force that balances that momentum for their intact neighbours. The others move with
the grid as usual.
This is what lets the two faces of a crack separate within one grid (003 §5.4).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .boundary import OffGridBoundaries
from .extension import IntegralMPMExtension, PDBodyExtension
from .geometry import bond_vectors, norm3

_SHIFT = np.int64(1 << 20)      # cell index range per axis in a key (+-2^19 cells)


@njit(cache=True, error_model="numpy")
def cell_keys(x, lo, inv_dx, n, out):
    """One int64 key per point's grid cell (the first n rows of x)."""
    dim = x.shape[1]
    half = _SHIFT // 2
    for p in range(n):
        k = np.int64(0)
        for a in range(dim):
            i = np.int64(math.floor((x[p, a] - lo[a]) * inv_dx)) + half
            k = k * _SHIFT + i
        out[p] = k


@njit(cache=True, error_model="numpy")
def bond_counts(offsets, status, n, broken, total):
    for p in range(n):
        c = 0
        for b in range(offsets[p], offsets[p + 1]):
            c += 1 - status[b]
        broken[p] = c
        total[p] = offsets[p + 1] - offsets[p]


@njit(cache=True, error_model="numpy")
def crack_failure(x, x0, offsets, slot, status, e_p, use_ep, p_cell, threshold, n_owned,
                  max_l, normal):
    """Step 2: break bonds with l > threshold; per owned point the largest l of its newly
    broken bonds (-inf if none) and that bond's unit direction. Returns half-bonds broken."""
    dim = x.shape[1]
    broken = 0
    for p in range(n_owned):
        max_l[p] = -np.inf
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            if q < 0:
                continue            # the model's pass breaks it (partner beyond the halo)
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            yl = norm3(y0, y1, y2)
            s = yl / norm3(X0, X1, X2) - 1.0
            ep = e_p[b] if use_ep else 0.0
            lval = (s - ep) / (1.0 + 0.5 * (p_cell[p] + p_cell[q]))
            if lval > threshold:
                status[b] = 0
                broken += 1
                if lval > max_l[p]:
                    max_l[p] = lval
                    normal[p, 0] = y0 / yl
                    normal[p, 1] = y1 / yl
                    if dim == 3:
                        normal[p, 2] = y2 / yl
    return broken


@njit(cache=True, error_model="numpy")
def cut_bonds(x, offsets, slot, status, n_owned, centres, normals, radius, reach):
    """Step 3: break intact bonds whose segment crosses a plane (point, unit normal) with its
    midpoint within ``radius`` of the point. Symmetric in the two ends (products and the
    midpoint 0.5 (x_p + x_q) are commutative). ``reach`` >= radius + the longest intact bond
    bounds |x_p - c| for a cut bond (a pure skip, so both ends still decide alike). Returns
    half-bonds broken."""
    dim = x.shape[1]
    n_planes = centres.shape[0]
    broken = 0
    for p in range(n_owned):
        for k in range(n_planes):
            d2 = 0.0
            for a in range(dim):
                t = x[p, a] - centres[k, a]
                d2 += t * t
            if d2 > reach * reach:
                continue
            for b in range(offsets[p], offsets[p + 1]):
                if status[b] == 0:
                    continue
                q = slot[b]
                if q < 0:
                    continue
                dp = 0.0
                dq = 0.0
                for a in range(dim):
                    dp += normals[k, a] * (x[p, a] - centres[k, a])
                    dq += normals[k, a] * (x[q, a] - centres[k, a])
                if not dp * dq < 0.0:
                    continue
                dm = 0.0
                for a in range(dim):
                    dm += normals[k, a] * (0.5 * (x[p, a] + x[q, a]) - centres[k, a])
                r2 = 0.0
                for a in range(dim):
                    t = 0.5 * (x[p, a] + x[q, a]) - centres[k, a] - dm * normals[k, a]
                    r2 += t * t
                if r2 <= radius * radius:
                    status[b] = 0
                    broken += 1
    return broken


class SerialComm:
    """The one-rank stand-in for Domain.allgather (serial drivers and tests)."""

    def allgather(self, obj):
        return [obj]


class CrackPlanes:
    """003 §5.4 failure for one PD body (module docstring).

    Parameters
    ----------
    threshold : l_threshold.
    cell_size : the grid spacing (cells of p_inactive and of the planes).
    domain_lo : origin of the cell lattice.
    radius : max(dx, delta), the cut's reach in the plane.
    bond_reach : the longest intact bond (the PD halo reach: (delta + h/2)(1 + s_max)).
    """

    def __init__(self, threshold: float, cell_size: float, domain_lo, radius: float,
                 bond_reach: float):
        self.threshold = float(threshold)
        self.cell_size = float(cell_size)
        self.lo = np.ascontiguousarray(domain_lo, dtype=np.float64)
        self.radius = float(radius)
        self.reach = float(radius + bond_reach)
        self.planes = 0             # planes made, summed over steps (diagnostics)

    def _keys(self, x, n):
        out = np.empty(n, np.int64)
        cell_keys(x, self.lo[: x.shape[1]], 1.0 / self.cell_size, n, out)
        return out

    def inactive_fraction(self, pts, comm) -> np.ndarray:
        """p_inactive of the cell of every owned + halo point (step 1)."""
        b = pts.bonds
        n = pts.n_owned
        broken = np.empty(n, np.int64)
        total = np.empty(n, np.int64)
        bond_counts(b.offsets, b.status, n, broken, total)
        keys = self._keys(pts.x, len(pts.x))
        own = keys[:n]
        damaged = np.unique(np.concatenate(comm.allgather(np.unique(own[broken > 0]))))
        p_cell = np.zeros(len(pts.x))
        if len(damaged) == 0:
            return p_cell
        idx = np.searchsorted(damaged, own)
        idx_ok = (idx < len(damaged)) & (damaged[np.minimum(idx, len(damaged) - 1)] == own)
        sums = np.zeros((2, len(damaged)), np.int64)
        np.add.at(sums[0], idx[idx_ok], broken[idx_ok])
        np.add.at(sums[1], idx[idx_ok], total[idx_ok])
        sums = np.sum(comm.allgather(sums), axis=0)
        frac = np.where(sums[1] > 0, sums[0] / np.maximum(sums[1], 1), 0.0)
        at = np.searchsorted(damaged, keys)
        hit = (at < len(damaged)) & (damaged[np.minimum(at, len(damaged) - 1)] == keys)
        p_cell[hit] = frac[at[hit]]
        return p_cell

    def apply(self, pts, comm, plastic: np.ndarray | None = None) -> int:
        """Steps 1-3 on the owned points' bonds; returns the half-bonds broken here."""
        b = pts.bonds
        n = pts.n_owned
        dim = pts.x.shape[1]
        p_cell = self.inactive_fraction(pts, comm)
        max_l = np.empty(n)
        normal = np.zeros((n, dim))
        e_p = plastic if plastic is not None else np.zeros(0)
        broken = crack_failure(pts.x, pts.x0, b.offsets, b.slot, b.status, e_p,
                               plastic is not None, p_cell, self.threshold, n, max_l, normal)
        new = np.flatnonzero(np.isfinite(max_l))
        records = comm.allgather((pts.ids[new], pts.x[new], max_l[new], normal[new]))
        ids = np.concatenate([r[0] for r in records])
        if len(ids) == 0:
            return broken
        order = np.argsort(ids, kind="stable")
        x_new = np.concatenate([r[1] for r in records])[order]
        l_new = np.concatenate([r[2] for r in records])[order]
        n_new = np.concatenate([r[3] for r in records])[order]
        keys = self._keys(x_new, len(x_new))
        centres, normals = [], []
        for key in np.unique(keys):
            rows = np.flatnonzero(keys == key)             # ascending id
            centres.append(x_new[rows].sum(axis=0) / len(rows))
            normals.append(n_new[rows[np.argmax(l_new[rows])]])
        centres = np.ascontiguousarray(centres)
        normals = np.ascontiguousarray(normals)
        self.planes += len(centres)
        return broken + cut_bonds(pts.x, b.offsets, b.slot, b.status, n, centres, normals,
                                  self.radius, self.reach)


# -- engine extensions (Peridynamic.make_extension picks these for ``crack_threshold``) ------
def _crack_planes_of(ext) -> CrackPlanes:
    material, sim = ext.material, ext.sim
    prm = material.params
    return CrackPlanes(prm["crack_threshold"], sim.dx, sim.domain_lo,
                       max(sim.dx, material.delta),
                       material.family_radius() * (1.0 + prm["max_bond_stretch"]))


class CrackPlaneForces:
    """Mixin over a PDExtension: the crack-plane pass before the model's own pass."""

    def compute_forces(self, start, stop):
        if not hasattr(self, "crack_planes"):
            self.crack_planes = _crack_planes_of(self)
        plastic = self.bonds.state.get("plastic_stretch")
        self.broken += self.crack_planes.apply(self.pts, self.sim.domain, plastic)
        return super().compute_forces(start, stop)


class CrackPlanePDBody(CrackPlaneForces, PDBodyExtension):
    """``integration = "pd"`` with crack planes."""


class CrackPlaneIntegralMPM(CrackPlaneForces, IntegralMPMExtension):
    """``integration = "grid"`` with crack planes and, unless ``two_time_integration =
    false``, particles with a broken bond moving by their own PD force (module docstring)."""

    def particle_forces(self, sim, dt: float):
        for start, stop, f in super().particle_forces(sim, dt):
            self._own = None
            if self.material.params["two_time_integration"]:
                p = sim.particles
                rows = np.flatnonzero(p["damage"][start:stop] > 0.0)
                if len(rows):
                    at = start + rows
                    self._own = (at, p["x"][at].copy(), p["v"][at].copy(), f[rows].copy())
            yield start, stop, f

    def after_g2p(self, sim, dt: float) -> None:
        if getattr(self, "_own", None) is None:
            return
        at, x_n, v_n, f = self._own
        p = sim.particles
        v = v_n + dt * (f / p["mass"][at, None] + sim.gravity[: sim.dim])
        if not hasattr(self, "boundaries"):
            self.boundaries = OffGridBoundaries(sim.scene)
        # Off the grid: walls, colliders and prescribed sets per particle (pd/boundary.py).
        self.boundaries.apply(sim, at, x_n, v, dt)
        p["v"][at] = v
        p["x"][at] = x_n + dt * v
        self._own = None


def make_crack_plane_extension(sim, material):
    cls = CrackPlaneIntegralMPM if material.on_grid else CrackPlanePDBody
    return cls(sim, material)

"""A serial PD-only integrator (003 Alg. 2) over plain arrays: verification and the reference
for the engine's `integration = "pd"`.

One step: refresh the halo rows (here: periodic images), failure and the per-particle state
(theta or K, F, then the material's stress) on owners, refresh that state in the halo, bond
forces (003 eq. 4.1 times V_p), then symplectic Euler v += dt (f + b V)/m, x += dt v.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bonds import Bonds
from .families import Family
from .geometry import damage, weighted_volume_sums
from .moduli import stable_time_step


@dataclass
class PDPoints:
    """Owned points (rows ``0..n_owned-1``) followed by halo points, as the kernels see them.

    x0, x : (n, d) reference and current positions; vol : (n,) volumes; ids : (n,) global ids;
    bonds : the owned points' half-bonds (slots index these rows); fields : persistent
    per-point model fields (owned + halo rows, e.g. the LPS weighted volume "m"), which move
    and checkpoint with their particles; ghosts : the clamp's ghost-bond history of the owned
    points (clamp.ghost_store; None when the model keeps none)."""

    x0: np.ndarray
    x: np.ndarray
    vol: np.ndarray
    ids: np.ndarray
    n_owned: int
    bonds: Bonds
    fields: dict = field(default_factory=dict)
    ghosts: Bonds | None = None


def bond_forces(model, pts: PDPoints, force: np.ndarray, refresh_halo) -> int:
    """Failure and state on the owners, the state's halo rows refreshed by
    ``refresh_halo(arrays)`` (arrays over owned + halo rows), then the bond forces into
    ``force`` (Alg. 2 lines 3-14). Returns the half-bonds broken."""
    broken = model.update_state(pts)
    if model.halo_fields:
        refresh_halo({k: getattr(model, k) for k in model.halo_fields})
    return broken + model.forces(pts, force)


class PDBody:
    """A PD body integrated by its own bond forces.

    Parameters
    ----------
    x0, vol, ids : owned points (reference positions, volumes, global ids).
    density : mass density (scalar or per point).
    family : `families.find_families` over these points (images appended for a periodic box).
    model : a `pmb.PMB`, `lps.LPS` or `correspondence.Correspondence`.
    velocity : initial velocities (n, d).
    body_force : force per volume (d,).
    """

    def __init__(self, x0, vol, ids, density, family: Family, model, velocity=None,
                 body_force=None):
        x0 = np.ascontiguousarray(x0, dtype=np.float64)
        n, dim = x0.shape
        self.dim = dim
        self.src = family.image_source if family.image_source is not None else \
            np.empty(0, np.int64)
        self.shift = family.image_shift if family.image_shift is not None else \
            np.empty((0, dim))
        vol = np.asarray(vol, dtype=np.float64)
        ids = np.asarray(ids, dtype=np.int64)
        x0_all = np.concatenate([x0, x0[self.src] + self.shift])
        self.pts = PDPoints(x0_all, x0_all.copy(), np.concatenate([vol, vol[self.src]]),
                            np.concatenate([ids, ids[self.src]]), n, family.bonds)
        self.rho = np.broadcast_to(np.asarray(density, np.float64), (n,)).copy()
        self.mass = self.rho * vol
        self.v = np.zeros((n, dim)) if velocity is None else \
            np.array(velocity, dtype=np.float64).reshape(n, dim)
        self.body_force = np.zeros(dim) if body_force is None else np.asarray(body_force, float)
        self.force = np.zeros((n, dim))
        self.model = model
        self.fixed: np.ndarray | None = None      # rows whose velocity is prescribed
        self.fixed_velocity: np.ndarray | None = None
        self.broken = 0
        self.time = 0.0
        self.steps = 0
        self.refresh_halo_positions()
        model.setup(self.pts)
        self._refresh_images(self.pts.fields)
        b = self.pts.bonds
        self.initial_weighted_volume = np.empty(n)
        weighted_volume_sums(self.pts.x0, self.pts.vol, b.offsets, b.slot, b.status, b.weight,
                             n, self.initial_weighted_volume)

    @property
    def x(self) -> np.ndarray:
        return self.pts.x[: self.pts.n_owned]

    def refresh_halo_positions(self) -> None:
        """Image rows follow their sources (a box that does not deform)."""
        n = self.pts.n_owned
        if len(self.src):
            self.pts.x[n:] = self.pts.x[self.src] + self.shift

    def _refresh_images(self, arrays: dict) -> None:
        n = self.pts.n_owned
        if len(self.src):
            for arr in arrays.values():
                arr[n:] = arr[self.src]

    def compute_forces(self) -> int:
        """Failure, state and bond forces at the current positions (Alg. 2 lines 3-14);
        writes self.force; returns the half-bonds broken."""
        self.refresh_halo_positions()
        return bond_forces(self.model, self.pts, self.force, self._refresh_images)

    def step(self, dt: float) -> None:
        """One symplectic Euler step (Alg. 2 line 15)."""
        self.model.dt = dt          # rate models (viscoelastic_lps) integrate over the step
        self.broken += self.compute_forces()
        n = self.pts.n_owned
        vol = self.pts.vol[:n]
        self.v += dt * (self.force + vol[:, None] * self.body_force) / self.mass[:, None]
        if self.fixed is not None:
            self.v[self.fixed] = self.fixed_velocity
        self.pts.x[:n] += dt * self.v
        self.time += dt
        self.steps += 1

    def stable_dt(self, safety: float = 0.8) -> float:
        """The issue's rule dt = safety sqrt(2 rho / sum_q V_q c / |X|) (moduli.py)."""
        return stable_time_step(self.pts.x0, self.pts.vol, np.concatenate(
            [self.rho, self.rho[self.src]]), self.pts.bonds,
            self.model.time_step_micromodulus(), self.pts.n_owned, safety)

    def damage(self) -> np.ndarray:
        b = self.pts.bonds
        out = np.empty(self.pts.n_owned)
        damage(self.pts.vol, b.offsets, b.slot, b.status, b.weight,
               self.initial_weighted_volume, self.pts.n_owned, out)
        return out

    def kinetic_energy(self) -> float:
        return 0.5 * float(np.sum(self.mass[:, None] * self.v * self.v))

    def momentum(self) -> np.ndarray:
        return (self.mass[:, None] * self.v).sum(axis=0)

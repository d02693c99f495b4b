"""PD bodies on any number of ranks (003 Alg. 2, `integration = "pd"`): the serial
`integrator.PDBody` step over a `ParticleSet` decomposed by a `Domain`, with bonds crossing
ranks through the PD halo (hpcmpm/parallel/pd_halo.py).

Results are bitwise those of the serial integrator on any rank count: each particle sums its
bonds in partner-id order, both ends of a bond evaluate it from bitwise equal copies (the
halo ships values, never recomputes them), and the halo reach makes bond breaking independent
of the decomposition. The particle set must hold the fields ``x0`` (reference positions) and
``pd_<name>`` for each of the model's ``persistent_fields``; with ``pd_wvol0`` and
``damage`` fields it also writes the damage phi each step.
"""

from __future__ import annotations

import math

import numpy as np

from ..parallel.pd_halo import PDHalo, migrate_with_bonds
from .families import family_radius, find_families
from .geometry import damage, weighted_volume_sums
from .integrator import PDPoints, bond_forces
from .moduli import silling_askari_steps


class DistributedPDBody:
    """PD-only particles of a ParticleSet on a Domain.

    Parameters
    ----------
    domain, particles : the decomposition and this rank's particles (all of them PD here).
    model : a PMB, LPS or Correspondence; its critical stretch is capped at
        ``max_bond_stretch`` (the halo reach assumes every bond beyond it is broken).
    spacing, delta, influence, partial_volumes, precracks : the family (families.py).
    max_bond_stretch : s_reach (default 1).
    skin : halo skin (default half a spacing): the plan is rebuilt, and particles migrate,
        when a particle moved more than skin/2 since the last build.
    """

    def __init__(self, domain, particles, model, spacing: float, delta: float,
                 influence: str = "constant", partial_volumes: bool = True, precracks=None,
                 max_bond_stretch: float = 1.0, skin: float | None = None, body_force=None):
        self.domain = domain
        self.particles = particles
        self.model = model
        model.s0 = min(model.s0, float(max_bond_stretch))
        radius = family_radius(delta, spacing, partial_volumes)
        self.skin = 0.5 * spacing if skin is None else float(skin)
        # s_reach: the critical stretch, or max_bond_stretch when that is smaller.
        self.halo = PDHalo(domain, radius * (1.0 + model.s0), self.skin)
        self.body_force = np.zeros(domain.dim) if body_force is None else \
            np.asarray(body_force, np.float64)
        self.persistent = tuple(model.persistent_fields)
        self.stale = True
        self.steps = 0
        self.broken = 0
        self.migrated = 0     # particles that changed rank, summed over ranks and steps
        # Families in the reference configuration, over owned + halo points.
        p = particles
        self._rebuild(bonds=None)
        family = find_families(self.pts.x0, self.pts.ids, p.n, spacing, delta,
                               influence=influence, partial_volumes=partial_volumes,
                               precracks=precracks, image_period=domain.period_lengths(),
                               homes=self.halo.homes(p["x0"]))
        self.bonds = family.bonds
        self.pts.bonds = self.bonds
        model.setup(self.pts)
        for name in self.persistent:
            p[f"pd_{name}"][...] = self.pts.fields[name][: p.n]
        if "pd_wvol0" in p:
            weighted_volume_sums(self.pts.x0, self.pts.vol, self.bonds.offsets,
                                 self.bonds.slot, self.bonds.status, self.bonds.weight, p.n,
                                 p["pd_wvol0"])
        self.stale = True

    def _static(self) -> dict[str, np.ndarray]:
        p = self.particles
        out = {"id": p["id"], "x0": p["x0"], "vol0": p["vol0"], "x": p["x"]}
        out.update({f"pd_{k}": p[f"pd_{k}"] for k in self.persistent})
        return out

    def _rebuild(self, bonds) -> None:
        """A new halo plan; the points view of owned + halo rows; slots resolved."""
        p = self.particles
        halo = self.halo.build(p["x"], self._static())
        cat = lambda name: np.concatenate([p[name], halo[name]])  # noqa: E731
        self.pts = PDPoints(cat("x0"), cat("x"), cat("vol0"), cat("id"), p.n, bonds,
                            {k: cat(f"pd_{k}") for k in self.persistent})
        if bonds is not None:
            bonds.resolve_slots(self.pts.ids, self.pts.x0, self.domain.period_lengths())
        self.model.resize(len(self.pts.x))

    def step(self, dt: float) -> None:
        """Alg. 2: halo positions (a new plan, with migration, when stale), failure and
        state, state halo, forces, symplectic Euler."""
        p = self.particles
        if self.stale or self.halo.stale(p["x"]):
            self._migrate_and_rebuild()
        else:
            self.pts.x[: p.n] = p["x"]
            self.halo.refresh({"x": p["x"]}, {"x": self.pts.x[p.n:]})
        n = p.n
        force = np.empty((n, self.domain.dim))
        self.model.dt = dt          # rate models (viscoelastic_lps) integrate over the step
        self.broken += bond_forces(self.model, self.pts, force, self.halo.refresh_rows(n))
        mass = p["mass"]
        p["v"][...] += dt * (force + p["vol0"][:, None] * self.body_force) / mass[:, None]
        p["x"][...] += dt * p["v"]
        if "damage" in p:
            damage(self.pts.vol, self.bonds.offsets, self.bonds.slot, self.bonds.status,
                   self.bonds.weight, p["pd_wvol0"], n, p["damage"])
        self.steps += 1

    def _migrate_and_rebuild(self) -> None:
        """Particles change rank only together with a new plan (as LAMMPS exchanges atoms
        only when it re-neighbours): between plans an owner stays within skin/2 of where it
        was at the build, inside its box then, which the plan's reach + skin covers."""
        self.migrated += migrate_with_bonds(self.domain, self.particles, self.bonds)
        self._rebuild(self.bonds)
        self.stale = False

    def stable_dt(self, safety: float = 0.8) -> float:
        """The issue's rule over all ranks (moduli.stable_time_step). Collective."""
        if self.stale:
            self._migrate_and_rebuild()
        rho = np.concatenate([self.particles["mass"] / self.particles["vol0"],
                              np.zeros(len(self.pts.x) - self.particles.n)])
        b = self.bonds
        out = np.empty(self.particles.n)
        local = silling_askari_steps(self.pts.x0, self.pts.vol, rho, b.offsets, b.slot,
                                     b.status, b.weight, self.model.time_step_micromodulus(),
                                     self.particles.n, out) if self.particles.n else math.inf
        return safety * self.domain.min(local)


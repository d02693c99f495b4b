"""The step extension of a peridynamic material (hpcmpm/materials/peridynamic.py).

What the engine calls, and when (Simulation.add_extension; one extension per PD material):

- ``integration = "pd"``: `PDBodyExtension.after_g2p(sim, dt)` after the materials' state
  update, before migration: 003 Alg. 2 on the material's (off-grid) particles: failure,
  theta or K/F and the stress, force eq. 4.1, v += dt (f/m + g), x += dt v, damage.
- ``integration = "grid"``: `IntegralMPMExtension.particle_forces(sim, dt)` during P2G (the
  force channel, phase "forces"): failure, state and bond forces at x^n, yielded as
  (start, stop, f) for the material's rows; the grid scatters dt sum_p w_ip f_p (003 eq. 5.2
  corrected).

Both first bring the side structures up to date with the particle rows (every call, on every
rank, collectively): bond rows follow the particle rows by id after the engine's sort,
migration or rebalance (`redistribute_segments` fetches the segments of particles that
changed rank); the PD halo plan is rebuilt when particles changed rank or one moved more than
skin/2 since the last build, else only positions are refreshed. Bonds are made once, at the
first call, in the reference configuration (x0 = x then; x0 is a particle field, NaN until
set, so particles that become PD later get their x0 when they do).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from pathlib import Path

import numpy as np

from ..errors import SceneError
from ..parallel.pd_halo import PDHalo, align_rows, redistribute_segments
from .bonds import Bonds
from .boundary import OffGridBoundaries
from .clamp import face_names
from .families import find_families
from .geometry import break_stretched, damage, weighted_volume_sums
from .integrator import PDPoints, bond_forces
from .load import add_bond_load, bond_cost

log = logging.getLogger(__name__)


class PDExtension:
    """The PD state of one material on one rank (module docstring); bonds checkpoint with
    `CheckpointedBonds` (below)."""

    def __init__(self, sim, material):
        self.sim = sim
        self.material = material
        self.group = sim.materials.index(material)
        self.model = material.make_model()
        self.persistent = tuple(self.model.persistent_fields)
        prm = material.params
        self.radius = material.family_radius()
        # s_reach = the critical stretch, or max_bond_stretch when smaller (the model's s0).
        self.reach = self.radius * (1.0 + self.model.s0)
        self.skin = prm["skin"] * material.spacing
        self.halo: PDHalo | None = None       # made at the first step (the domain exists)
        self.bonds = None
        self.ghosts = None      # the clamp's ghost-bond history (clamp.ghost_store) or None
        self.bond_ids = np.empty(0, np.int64)
        self.pts: PDPoints | None = None
        self.force = np.empty((0, sim.dim))
        self.broken = 0
        self._damage_at = 0
        self.redistributions = 0
        self.bond_cost = bond_cost(sim.dim, self.model.name)     # c_b (pd/load.py)

    # -- keeping the side structures in step with the particles -------------------------------
    def _rows(self):
        start, stop = self.sim.group_slices[self.group]
        return start, stop

    def _static(self, start, stop) -> dict[str, np.ndarray]:
        p = self.sim.particles
        out = {"id": p["id"][start:stop], "x0": p["x0"][start:stop],
               "vol0": p["vol0"][start:stop], "x": p["x"][start:stop]}
        out.update({f"pd_{k}": p[f"pd_{k}"][start:stop] for k in self.persistent})
        return out

    def _rebuild(self, start, stop) -> None:
        static = self._static(start, stop)
        halo = self.halo.build(static["x"], static)
        cat = lambda k: np.concatenate([static[k], halo[k]])  # noqa: E731
        self.pts = PDPoints(cat("x0"), cat("x"), cat("vol0"), cat("id"), stop - start,
                            self.bonds, {k: cat(f"pd_{k}") for k in self.persistent},
                            self.ghosts)
        if self.bonds is not None:
            self.bonds.resolve_slots(self.pts.ids, self.pts.x0,
                                     self.sim.domain.period_lengths())
        self.model.resize(len(self.pts.x))

    def _where(self, key: str = "") -> str:
        """The material's place in the scene file, for messages in the validator's format."""
        return f"{self.sim.scene.path}: materials[{self.group}]" + (f".{key}" if key else "")

    def _check_memory(self, n: int) -> None:
        """Refuse a horizon whose bonds would not fit: an estimate before allocating, from
        an interior family's count (collective; the same SceneError on every rank). The
        start-up memory check (hpcmpm/startup.py) counts the bonds too; this one sees the
        rank's actual share."""
        per_particle = self.material.half_bonds_per_particle()
        need = n * self.material.side_bytes_per_particle()
        try:
            memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            memory = math.inf
        worst = self.sim.domain.max(float(need))
        if worst > 0.5 * memory:
            raise SceneError(
                f"{self._where('horizon')}: {per_particle} half-bonds per particle need about "
                f"{worst / 2**30:.1f} GiB on one rank, more than half of its "
                f"{memory / 2**30:.1f} GiB: lower the horizon or use more ranks")

    def _check_distinct(self, x0: np.ndarray) -> None:
        """Refuse particles of this material at the same reference place (bodies that overlap
        sample their shared lattice points twice): their bond has no length, so its stretch
        and force are undefined, and the run stopped at its first step as a numerical
        instability whose hint (a smaller time step) could not help. Coincident particles
        have the same owner, so each rank looks at its own (collective)."""
        cells = np.round(x0 / (1e-6 * self.material.spacing))
        repeated = len(x0) - len(np.unique(cells, axis=0)) if len(x0) else 0
        total = self.sim.domain.sum(int(repeated))
        if total:
            raise SceneError(
                f"{self._where()}: {total} particle(s) of material "
                f"{self.material.spec.name!r} lie where another of its particles lies (bodies "
                f"that overlap): a peridynamic bond needs two distinct places; make its "
                f"bodies disjoint or merge them into one")

    def _initialize(self, start, stop) -> None:
        """Families in the reference configuration (collective)."""
        self._check_memory(stop - start)
        p = self.sim.particles
        x0 = p["x0"][start:stop]
        unset = np.isnan(x0[:, 0])
        x0[unset] = p["x"][start:stop][unset]
        self._check_distinct(x0)
        self._rebuild(start, stop)
        prm = self.material.params
        family = find_families(self.pts.x0, self.pts.ids, stop - start, self.material.spacing,
                               self.material.delta, influence=prm["influence"],
                               partial_volumes=prm["partial_volumes"],
                               precracks=prm["precracks"],
                               image_period=self.sim.domain.period_lengths(),
                               homes=self.halo.homes(x0))
        self.bonds = family.bonds
        self.pts.bonds = self.bonds
        self.bond_ids = p["id"][start:stop].copy()
        self.model.setup(self.pts)
        self.ghosts = self.pts.ghosts
        for k in self.persistent:
            p[f"pd_{k}"][start:stop] = self.pts.fields[k][: stop - start]
        weighted_volume_sums(self.pts.x0, self.pts.vol, self.bonds.offsets, self.bonds.slot,
                             self.bonds.status, self.bonds.weight, stop - start,
                             p["pd_wvol0"][start:stop])
        p["active_bonds"][start:stop] = self.bonds.intact_counts()
        lonely = self.sim.domain.sum(int(np.sum(self.bonds.counts() == 0)))
        if lonely and self.sim.domain.rank == 0:
            log.warning("%s: warning: %d particle(s) of material %r have no bond (horizon "
                        "%.4g, spacing %.4g): they move freely", self._where(), lonely,
                        self.material.spec.name, self.material.delta, self.material.spacing)
        faces = getattr(self.model, "clamp_faces", ())
        if len(faces) and self.sim.domain.rank == 0:
            # The default clamp = "auto" changes the physics at a wall: say where it acts.
            log.info("material %r: PD clamp (mirror-image bonds) at the sticky walls %s; "
                     "clamp = \"none\" turns it off", self.material.spec.name,
                     ", ".join(face_names(faces, self.sim.scene)))
        # The halo was built before the persistent fields existed: ship them now.
        self._rebuild(start, stop)

    def prepare(self) -> tuple[int, int]:
        """Bond rows and halo in step with the particles; positions refreshed. Collective."""
        start, stop = self._rows()
        domain = self.sim.domain
        if self.halo is None:
            self.halo = PDHalo(domain, self.reach, self.skin)
        if self.bonds is None:
            self._initialize(start, stop)
            return start, stop
        if self.pts is None:         # bonds restored from a checkpoint
            self._rebuild(start, stop)
        ids = self.sim.particles["id"][start:stop]
        moved = domain.any(not np.array_equal(ids, self.bond_ids))
        if moved:
            local = len(ids) == len(self.bond_ids) and \
                np.array_equal(np.sort(ids), np.sort(self.bond_ids))
            # The ghost store's rows are the bonds' rows (clamp.ghost_store).
            segments = [self.bonds] + ([self.ghosts] if self.ghosts is not None else [])
            if domain.min(float(local)) > 0:     # only reordered (a sort): no exchange
                for b in segments:
                    align_rows(b, self.bond_ids, ids)
            else:
                for b in segments:
                    redistribute_segments(domain, b, self.bond_ids, ids)
                self.redistributions += 1
            self.bond_ids = ids.copy()
        x = self.sim.particles["x"][start:stop]
        # Rebuild after a reorder too: the halo plan's send lists name rows.
        if moved or self.halo.stale(x):
            self._rebuild(start, stop)
        else:
            n = stop - start
            self.pts.x[:n] = x
            self.halo.refresh({"x": x}, {"x": self.pts.x[n:]})
        return start, stop

    def compute_forces(self, start, stop) -> np.ndarray:
        """Failure, state (with the state halo) and bond forces of the rows [start, stop)."""
        n = stop - start
        if len(self.force) != n:
            self.force = np.empty((n, self.sim.dim))
        self.broken += bond_forces(self.model, self.pts, self.force, self.halo.refresh_rows(n))
        return self.force

    def strain_energy(self, sim) -> float:
        """Bond strain energy of this rank's PD particles, sum_p V_p W_p at the current
        positions (each bond once: half its micropotential at each end), for the diagnostics'
        elastic energy (`Simulation.diagnostics`). Bonds stretched past s0, which the next
        force pass breaks, carry none; nothing of the run's state changes. Collective (the
        bond rows and the halo are brought up to date first, as the next step would)."""
        if self.bonds is None:          # no step yet: x = x0 when the bonds are made
            return 0.0
        self.prepare()
        energy = getattr(self.model, "strain_energy", None)
        if energy is None:
            return 0.0
        b, pts = self.bonds, self.pts
        status = b.status.copy()
        break_stretched(pts.x, pts.x0, b.offsets, b.slot, status,
                        getattr(self.model, "s0", math.inf), pts.n_owned)
        trial = Bonds(b.offsets, b.partner, b.weight, status, b.slot, b.state)
        return energy(dataclasses.replace(pts, bonds=trial))

    def write_damage(self, start, stop) -> None:
        """phi (003 eq. 4.8) of the rows; only when bonds broke since the last call (the
        rows' values otherwise stand, whatever the reordering, since they move with their
        particles)."""
        if self.broken == self._damage_at:
            return
        self._damage_at = self.broken
        p, b = self.sim.particles, self.bonds
        damage(self.pts.vol, b.offsets, b.slot, b.status, b.weight, p["pd_wvol0"][start:stop],
               stop - start, p["damage"][start:stop])
        p["active_bonds"][start:stop] = b.intact_counts()

    def add_load(self, sim, weights: np.ndarray) -> None:
        """`Simulation.load_weights`: each particle of this material costs c_b times its
        active half-bonds more (pd/load.py), in the weights' integer units; before the bonds
        exist, an interior family's count. Rows found by group (any order: between steps)."""
        p = sim.particles
        rows = np.flatnonzero(p["group"] == self.group)
        add_bond_load(weights, rows, p["active_bonds"][rows], sim.particle_weight,
                      self.bond_cost, self.material.half_bonds_per_particle())


class _HalfBondRows:
    """Half-bonds as rows for `hpcmpm.io.checkpoint.write_checkpoint` (its particle-set
    interface): owner id, partner id, weight, status, image label and the per-bond state."""

    def __init__(self, dim: int, arrays: dict[str, np.ndarray]):
        self.dim = dim
        self.arrays = arrays
        self.n = len(arrays["owner"])

    def field_names(self) -> list[str]:
        return list(self.arrays)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]


def bonds_folder(out_dir, material_name: str) -> Path:
    """Where a PD material's bonds are checkpointed, beside the particle checkpoints."""
    return Path(out_dir) / f"pd_bonds_{material_name}"


def ghosts_folder(out_dir, material_name: str) -> Path:
    """Where a PD material's clamp ghost store (clamp.ghost_store) is checkpointed."""
    return Path(out_dir) / f"pd_ghost_bonds_{material_name}"


class CheckpointedBonds:
    """Bonds in checkpoints (mixin of PDExtension): ``pd_bonds_<material>/ckpt_<step>.h5``
    beside the particle checkpoint, written before it (a particle checkpoint that exists has
    its bonds), read back on any rank count and routed to the particles' new owners. The
    clamp's ghost store, where the model keeps one, goes the same way in
    ``pd_ghost_bonds_<material>/``."""

    def checkpoint_ids(self) -> np.ndarray:
        """Ids of the rows that own bond segments, in row order (SPB-MPM: its PD particles)."""
        p = self.sim.particles
        return p["id"][p["group"] == self.group].copy()

    def _segment_sets(self, out_dir):
        """(folder, segments or None) of the bonds and, with a clamp store, the ghosts."""
        name = self.material.spec.name
        out = [(bonds_folder(out_dir, name), self.bonds)]
        if getattr(getattr(self, "model", None), "ghost_states", ()):
            out.append((ghosts_folder(out_dir, name), self.ghosts))
        return out

    def write_checkpoint(self, out_dir, step: int, keep: int) -> None:
        from ..io.checkpoint import write_checkpoint

        for folder, segments in self._segment_sets(out_dir):
            b = segments if segments is not None else Bonds.empty(0)
            arrays = {"owner": np.repeat(self.bond_ids, b.counts()), "partner": b.partner,
                      "weight": b.weight, "status": b.status, "image": b.image,
                      **{f"state.{k}": v for k, v in b.state.items()}}
            meta = {"step": int(step), "time": float(self.sim.time),
                    "initialized": segments is not None}
            write_checkpoint(folder, self.sim.domain, _HalfBondRows(self.sim.dim, arrays),
                             meta, keep=keep)

    def restore(self, particle_checkpoint) -> None:
        """Bonds of the particle checkpoint at this path (collective); the first step then
        builds the halo instead of new families."""
        path = Path(particle_checkpoint)
        # Rows of this material in their current order, without sorting (a sort now would
        # change a grid scene's summation order against the uninterrupted run).
        ids = self.checkpoint_ids()
        restored = [_read_segments(folder / path.name, self.sim.domain, ids)
                    for folder, _ in self._segment_sets(path.parent)]
        if restored[0] is None:
            return
        self.bonds = restored[0]
        self.ghosts = restored[1] if len(restored) > 1 else None
        self.bond_ids = ids
        self.pts = None


def _read_segments(path, domain, ids) -> Bonds | None:
    """Half-bond rows of a checkpoint file, routed to the ranks that hold their owners and
    ordered as the rows ``ids`` with each segment in its written order (None: the
    checkpoint was written before the bonds were made). Collective."""
    from ..io.checkpoint import read_checkpoint
    from ..parallel.pd_halo import route_half_bonds

    rows, meta = read_checkpoint(path, domain)
    if not meta.get("initialized", False):
        return None
    rows = route_half_bonds(domain, rows, ids)
    row_of = {int(i): k for k, i in enumerate(ids)}
    owner_row = np.array([row_of[int(i)] for i in rows["owner"]], dtype=np.int64)
    # Checkpoints written before image labels existed have none: 0, the minimum image, which
    # is every bond's image while the family radius stays below half the period (and
    # `resolve_slots` falls back to the nearest copy for a partner bonded once).
    image = rows.get("image", np.zeros(len(owner_row), np.int8))
    order = np.lexsort((image, rows["partner"], owner_row))
    offsets = np.zeros(len(ids) + 1, np.int64)
    np.cumsum(np.bincount(owner_row, minlength=len(ids)), out=offsets[1:])
    return Bonds(offsets, rows["partner"][order], rows["weight"][order],
                 rows["status"][order],
                 state={k[6:]: v[order] for k, v in rows.items() if k.startswith("state.")},
                 image=image[order])


class PDBodyExtension(CheckpointedBonds, PDExtension):
    """``integration = "pd"``: 003 Alg. 2 after G2P on the off-grid PD particles; the
    domain walls and the analytic colliders act per particle (pd/contact.py)."""

    def __init__(self, sim, material):
        super().__init__(sim, material)
        self.boundaries = OffGridBoundaries(sim.scene)
        has_bodies = any(b.material == material.spec.name for b in sim.scene.bodies)
        if sim.uses_grid and has_bodies and sim.domain is not None and sim.domain.rank == 0:
            # Nothing couples off-grid PD particles to the grid's bodies: say so, or a
            # projectile passes through its target without a word (a material no body uses
            # has nothing to say it about).
            log.warning("%s: warning: material %r (integration = \"pd\") moves off the grid: "
                        "its bodies and the grid's bodies pass through each other (no contact); "
                        "integration = \"grid\" couples them through the grid", self._where(),
                        material.spec.name)

    def after_g2p(self, sim, dt: float) -> None:
        with sim.phase("pd"):
            start, stop = self.prepare()
            self.model.dt = dt      # rate models (viscoelastic_lps) integrate over the step
            f = self.compute_forces(start, stop)
            p = sim.particles
            v = p["v"][start:stop]
            x = p["x"][start:stop]
            v += dt * (f / p["mass"][start:stop, None] + sim.gravity[: sim.dim])
            self.boundaries.apply(sim, slice(start, stop), x, v, dt)   # pd/boundary.py
            x += dt * v
            self.write_damage(start, stop)


class IntegralMPMExtension(CheckpointedBonds, PDExtension):
    """``integration = "grid"``: bond forces through the force channel (003 eq. 5.2)."""

    def particle_forces(self, sim, dt: float):
        start, stop = self.prepare()
        self.model.dt = dt          # rate models (viscoelastic_lps) integrate over the step
        f = self.compute_forces(start, stop)
        self.write_damage(start, stop)
        yield start, stop, f

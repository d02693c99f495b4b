"""Particles, grid block, materials and boundaries of one rank, and the phases of a step.

`Simulation.step` hands the step to the scene's integrator (`hpcmpm.solvers`), which calls the
phases below in order: each phase is a numba kernel over plain arrays, and the only inter-rank
traffic is the `Domain` verbs between them. The run loop (time-step choice, output,
checkpoints) lives in `hpcmpm.runner`.
"""

from __future__ import annotations

import logging

import numpy as np

from .boundaries import build_boundaries, build_prescribed
from .errors import InstabilityError, SceneError
from .kernels.grid import update_velocity
from .kernels.particles import (cell_sort_keys, counting_sort_order,
                                momentum_and_kinetic_energy, scan_health)
from .kernels.shape import ORDERS, inverse_inertia_factor
from .kernels.transfer import APIC, FLIP, GATHER, SCATTER, SCATTER_FORCES, SCHEMES, static
from .kernels.volume import GATHER_VOLUME, SCATTER_VOLUME, nodal_ratio
from .materials import Material, make_material
from .solvers import make_integrator
from .state import (DEFORMATION_FIELDS, SCALAR, TENSOR, VECTOR, FieldSpec, GridBlock,
                    ParticleSet)

log = logging.getLogger(__name__)

# How many broken particles an instability report names.
MAX_REPORTED = 8


def deformation_mode(materials, needs_velocity_gradient: bool = False) -> str:
    """What G2P does with the velocity gradient (`hpcmpm.kernels.deformation`): ``"L"``
    (store it) when a material or the integrator needs it, ``"J"`` when every material's
    stress needs det F only, else ``"F"``."""
    if needs_velocity_gradient or any(m.deformation == "L" for m in materials):
        return "L"
    return "J" if materials and all(m.deformation == "J" for m in materials) else "F"


def deformation_fields(materials, mode: str) -> dict[str, FieldSpec]:
    """The deformation state the particles carry in ``mode``: F or J, or in mode L the
    velocity gradient plus the F and J that materials of the other kinds advance from it."""
    if mode != "L":
        return {mode: DEFORMATION_FIELDS[mode]}
    specs = {"L": FieldSpec(TENSOR)}
    for kind in ("F", "J"):
        if any(m.deformation == kind for m in materials):
            specs[kind] = DEFORMATION_FIELDS[kind]
    return specs


def grid_in_use(scene, materials) -> bool:
    """Whether a body of the scene is made of a material the grid carries (`Material.on_grid`).
    A scene without bodies, whose particles the caller gives (benchmarks, tests), counts
    every material."""
    used = {scene.material_index(b.material) for b in scene.bodies} if scene.bodies else \
        range(len(materials))
    return any(materials[g].on_grid for g in used)


def configured_materials(scene, dim: int) -> list[Material]:
    """The scene's materials, made and configured against the scene; a problem only the whole
    scene shows (a horizon below the spacing, a material named by another that is not there)
    is a `SceneError` in the scene's format: ``{file}: materials[i]: ...``."""
    materials = []
    for i, spec in enumerate(scene.materials):
        try:
            material = make_material(spec, dim)
            material.configure(scene)
        except SceneError as exc:
            # A material that names the file and its key itself (`configure`) keeps its line.
            raise SceneError([p if p.startswith(f"{scene.path}: ") else
                              f"{scene.path}: materials[{i}]: {p}" for p in exc.problems]) \
                from None
        materials.append(material)
    return materials


def particle_field_specs(materials, mode: str, transfer: str,
                         prescribed: bool) -> dict[str, FieldSpec]:
    """The particle fields a scene declares besides the core ones: its deformation state in
    ``mode``, its materials' own fields, ``C`` for APIC/MLS, ``prescribed`` when it has
    prescribed sets. One source for `Simulation.particle_fields` and the scene's check of
    ``output.fields``; ``materials`` are material classes or instances."""
    specs = deformation_fields(materials, mode)
    for material in materials:
        specs.update(material.fields)
    if SCHEMES[transfer] >= APIC:
        specs["C"] = FieldSpec(TENSOR)
    if prescribed:
        specs["prescribed"] = FieldSpec(SCALAR, "i4", -1)
    return specs


class Simulation:
    """Particles, grid block, materials and boundaries of one rank, and the step over them."""

    # Re-sort by cell at least this often even when no particle changed rank or group, so
    # P2G/G2P keep walking the grid in memory order as particles drift (a particle crosses a
    # cell in several steps at CFL < 1, so the order decays slowly). Sorting every step cost
    # 20 % of a 1-rank step of jelly_cube_3d; on the 2D benchmark scene (8192 particles) the
    # in-place sort costs 0.25 ms, and over 400 steps sorting every 8, 16, 32 steps or never
    # measured 0.426, 0.417, 0.413, 0.400 ms/step: the order decays slowly enough that 16
    # keeps the sort near 3 % of the step.
    sort_every = 16
    # Bytes of the stress chunk: it stays in L2 cache between the material kernel and P2G
    # (3641 particles in 3D, 8192 in 2D).
    stress_chunk_bytes = 256 * 1024

    def __init__(self, scene, domain, particles: ParticleSet | None = None):
        self.scene = scene
        self.domain = domain
        self.dim = scene.dim
        self.dx = float(scene.dx)
        self.domain_lo = np.asarray(scene.domain_lo, dtype=np.float64)
        self.order = ORDERS[scene.kernel]
        self.scheme = SCHEMES[scene.transfer]
        self.dinv_factor = inverse_inertia_factor(self.order)
        self._static_scheme, self._static_order = static(self.scheme), static(self.order)
        self.flip_alpha = float(getattr(scene, "flip_alpha", 0.0))
        # FLIP needs the pre-force grid velocity; every other scheme fuses the impulse into
        # the momentum and saves a grid field.
        self.split_force = self.scheme == FLIP
        self._static_split = static(self.split_force)
        self.gravity = np.zeros(3)
        self.gravity[: self.dim] = scene.gravity
        self.materials = configured_materials(scene, self.dim)
        self.integrator = make_integrator(getattr(scene, "integrator", "explicit"), self)
        # F, J alone, or the velocity gradient L (`deformation_mode`).
        self.deformation = deformation_mode(self.materials,
                                            self.integrator.needs_velocity_gradient)
        self.boundaries = build_boundaries(scene)
        self.prescribed = build_prescribed(scene)
        self.particles = particles if particles is not None else ParticleSet(
            self.dim, self.particle_fields())
        self.grid = GridBlock(self.dim, self.dx, self.domain_lo)
        self._scattered = ["mass", "momentum"] + (["impulse"] if self.split_force else []) + \
            [s.mark_field for s in self.prescribed]
        self._gathered = ["velocity"] + (["velocity_old"] if self.scheme == FLIP else [])
        for name in self._scattered + self._gathered:
            scalar = name == "mass" or name.startswith("prescribed_")
            self.grid.declare(name, SCALAR if scalar else VECTOR)
        self._dummy_vector = np.zeros((1,) * self.dim + (self.dim,))
        self._dummy_C = np.zeros((1, self.dim, self.dim))
        self.stress_chunk = self.stress_chunk_bytes // (8 * self.dim * self.dim)
        self._tau = np.empty((self.stress_chunk, self.dim, self.dim))
        self._zero_tau = np.zeros((0, self.dim, self.dim))  # scatter_mass_momentum only
        self._bad = np.empty(MAX_REPORTED, dtype=np.int64)
        self._keys = np.empty(0, dtype=np.int64)
        self._order = np.empty(0, dtype=np.int64)
        self._counts = np.empty(0, dtype=np.int64)
        self._needs_sort = True
        self.group_slices: list[tuple[int, int]] = []
        # Materials whose particles the grid carries, and those with a state update to run
        # after G2P (every on-grid material in mode L): an elastic scene has none.
        self._on_grid = [g for g, m in enumerate(self.materials) if m.on_grid]
        self._all_on_grid = len(self._on_grid) == len(self.materials)
        # A scene whose bodies are all off-grid peridynamic ones (integration = "pd"; an
        # on-grid material may still be there as a correspondence body's stress model) has
        # nothing on the grid: the integrators then skip every grid phase and no block is
        # ever allocated (the bodies move in their extension's after_g2p, walls and
        # prescribed sets act per particle there: pd/extension.py, pd/boundary.py).
        self.uses_grid = grid_in_use(scene, self.materials)
        self._state_groups = [g for g in self._on_grid if self.deformation == "L"
                              or self.materials[g].updates_state(self.deformation)]
        # simulation.volume_averaging = "increment": the materials whose change of J over
        # each step is averaged through the grid (`remember_volumes`, `average_volumes`);
        # none by default, and then no grid field, scratch array or phase exists for it.
        self._volume_groups = [g for g in self._on_grid
                               if getattr(scene, "volume_averaging", "none") != "none"
                               and self.materials[g].averages_volume(self.deformation)]
        self._x_old = np.empty((0, self.dim))
        self._J_old = np.empty(0)
        if self._volume_groups:
            self.grid.declare("volume_old", SCALAR)
            self.grid.declare("volume_new", SCALAR)
        self._state_dependent_speed = any(
            type(m).max_wave_speed is not Material.max_wave_speed for m in self.materials)
        # Step extensions (peridynamics, SPB): objects with optional `particle_forces(sim,
        # dt)` (the force channel into P2G) and `after_g2p(sim, dt)`; see `add_extension`.
        self.extensions: list = []
        self._force_sources: list = []
        self._after_g2p: list = []
        self._before_state: list = []
        self._stress_hooks: list = []
        # A material that works through a step extension (peridynamics, SPB-MPM) makes its
        # own (None: one it shares was made already).
        for material in self.materials:
            if hasattr(material, "make_extension"):
                extension = material.make_extension(self)
                if extension is not None:
                    self.add_extension(extension)
        self.time = 0.0
        self.step_index = 0
        # Optional ``forcing(sim, dt)`` that adds ``dt * b`` to particle velocities before P2G:
        # through P2G that is exactly the external nodal force sum_p w_ip m_p b_p.
        self.forcing = None
        self.sync_phases = False
        from .timers import PhaseTimers

        self.timers = PhaseTimers()

    # -- set-up ----------------------------------------------------------------------------
    def particle_fields(self) -> dict[str, FieldSpec]:
        """Union of the fields the materials and the chosen features declare."""
        return particle_field_specs(self.materials, self.deformation, self.scene.transfer,
                                    bool(self.scene.prescribed))

    def add_extension(self, extension) -> None:
        """Add a step extension: its ``particle_forces(sim, dt)`` (if any) yields
        ``(start, stop, f)`` with f (stop - start, dim) forces on particle rows [start, stop),
        scattered into the grid as ``dt sum_p w_ip f_p``; its ``after_g2p(sim, dt)`` (if
        any) runs after the materials' state update."""
        self.extensions.append(extension)
        if hasattr(extension, "particle_forces"):
            self._force_sources.append(extension)
        if hasattr(extension, "after_g2p"):
            self._after_g2p.append(extension)
        # SPB-MPM's re-transfer (003 Alg. 3): ``before_state(sim, dt)`` runs between G2P and
        # the materials' state update, so the update sees the corrected F or L.
        if hasattr(extension, "before_state"):
            self._before_state.append(extension)
        # SPB-MPM (003 eq. 6.10): ``stress_chunk(sim, g, start, stop, tau, dt)`` sees each
        # chunk's Kirchhoff stress between the material kernel and P2G (and may zero rows
        # of it); ``grid_scattered`` names scalar grid fields it scatters there, summed to
        # owners with the mass.
        if hasattr(extension, "stress_chunk"):
            self._stress_hooks.append(extension)
        for name in getattr(extension, "grid_scattered", ()):
            self.grid.declare(name, SCALAR)
            self._scattered.append(name)

    # Load-balance weight of a particle with no work besides the MPM step, in the integer
    # units of `load_weights` (1/64 resolves the measured cost of a PD half-bond, pd/load.py).
    particle_weight = 64

    def load_weights(self) -> np.ndarray | None:
        """Integer cost of each particle for the decomposition and rebalancing
        (`Domain.decompose`, `Domain.rebalance`): None (every particle costs the same)
        unless a step extension adds its particles' work (``add_load(sim, weights)``:
        peridynamic bonds, pd/extension.py and pd/spb.py). Integers, and a particle's own
        property, so the bisection's global sums are exact and rank-count independent; a
        power of two per particle, so uniform weights cut exactly as the count does."""
        sources = [e for e in self.extensions if hasattr(e, "add_load")]
        if not sources:
            return None
        weights = np.full(self.particles.n, self.particle_weight, dtype=np.int64)
        for source in sources:
            source.add_load(self, weights)
        return weights

    # -- the step --------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance by ``dt``: the sort, the integrator's grid part (explicit: 000 §3.3, Fig.
        3.1) when the grid is in use (`uses_grid`; else off-grid peridynamic bodies only),
        the extensions after G2P (peridynamic bodies, 003 Alg. 2), then migration."""
        self.sort_phase()
        if self.forcing is not None:
            self.forcing(self, dt)  # body force as a particle impulse (manufactured solutions)
        if self.uses_grid:
            self.integrator.grid_step(self, dt)
        self.after_g2p(dt)
        self.migrate()
        self.time += dt
        self.step_index += 1

    def phase(self, name: str):
        """Timer of one phase. With sync_phases (benchmarks only) every rank meets first, so
        a phase timer holds that phase's own work and the waiting is left out."""
        if self.sync_phases:
            self.domain.barrier()
        return self.timers(name)

    def sort_phase(self) -> None:
        with self.phase("sort"):
            self.sort_if_needed()

    def fit_grid(self) -> None:
        """Size the grid block to this step's support and zero it."""
        with self.phase("p2g"):
            self.grid.fit(*self.domain.grid_box(self.particles, self.order))

    def volume_scratch_bytes_per_particle(self) -> int:
        """Bytes per particle of volume averaging's copies of x and J (at the particles'
        capacity); 0 without it."""
        return 8 * (self.dim + 1) if self._volume_groups else 0

    def _volume_slices(self) -> list[tuple[int, int]]:
        """The nonempty row slices of the averaging materials (valid from the step's sort
        to its migration)."""
        slices = [self.group_slices[g] for g in self._volume_groups]
        return [(start, stop) for start, stop in slices if stop > start]

    def remember_volumes(self) -> None:
        """``simulation.volume_averaging``, before G2P: keep x^n and J^n of the averaging
        materials' rows (G2P moves x, and advances J in mode J) for `average_volumes`. A
        no-op without it."""
        if not self._volume_groups:
            return
        with self.phase("volume"):
            p = self.particles
            if len(self._J_old) < p.n:
                self._x_old = np.empty((p.capacity, self.dim))
                self._J_old = np.empty(p.capacity)
            x, J = p["x"], p["J"]
            for start, stop in self._volume_slices():
                self._x_old[start:stop] = x[start:stop]
                self._J_old[start:stop] = J[start:stop]

    def average_volumes(self) -> None:
        """``simulation.volume_averaging``, after the state update: the averaging materials'
        change of J over the step becomes its grid average at x^n
        (hpcmpm/kernels/volume.py). A no-op without it."""
        if not self._volume_groups:
            return
        p, grid = self.particles, self.grid
        slices = self._volume_slices()
        x_old, J_old, vol0, J = self._x_old, self._J_old, p["vol0"], p["J"]
        with self.phase("volume"):
            for start, stop in slices:
                SCATTER_VOLUME[self.dim](x_old[start:stop], vol0[start:stop],
                                         J_old[start:stop], J[start:stop], self._static_order,
                                         self.dx, self.domain_lo, grid.origin,
                                         grid["volume_old"], grid["volume_new"])
        with self.phase("halo"):
            self.domain.sum_ghosts_to_owners(grid, "volume_old", "volume_new")
        with self.phase("volume"):
            # Complete on owned nodes after the sum; ghost copies are overwritten below.
            nodal_ratio(grid["volume_old"].reshape(-1), grid["volume_new"].reshape(-1))
        with self.phase("halo"):
            self.domain.fill_ghosts(grid, "volume_new")
        with self.phase("volume"):
            for start, stop in slices:
                GATHER_VOLUME[self.dim](x_old[start:stop], J_old[start:stop],
                                        self._static_order, self.dx, self.domain_lo,
                                        grid.origin, grid["volume_new"], J[start:stop])

    def sum_ghosts(self) -> None:
        """After P2G: partial sums on other ranks' nodes go to their owners."""
        with self.phase("halo"):
            self.domain.sum_ghosts_to_owners(self.grid, *self._scattered)

    def fill_ghosts(self) -> None:
        """After the grid update: owners send the final velocities to the ghost copies."""
        with self.phase("halo"):
            self.domain.fill_ghosts(self.grid, *self._gathered)

    def migrate(self) -> None:
        with self.phase("migrate"):
            p = self.particles
            n_before = p.n
            sent = self.domain.migrate(p)
            if sent or p.n != n_before:
                self._needs_sort = True

    def sort_if_needed(self) -> None:
        """Sort particles by (material group, cell) so each material owns one contiguous
        slice and P2G/G2P walk the grid in memory order."""
        p = self.particles
        if not self._needs_sort and self.step_index % self.sort_every:
            return
        if len(self._keys) < p.n:
            self._keys = np.empty(p.capacity, dtype=np.int64)
            self._order = np.empty(p.capacity, dtype=np.int64)
        keys, order = self._keys[: p.n], self._order[: p.n]
        n_keys = cell_sort_keys(p["x"], p["group"], self.domain_lo, 1.0 / self.dx, keys)
        if n_keys <= 4 * p.n + 1024:
            # Dense key range (the usual case): counting sort, O(n), no allocation.
            if len(self._counts) < n_keys + 1:
                self._counts = np.empty(2 * n_keys + 1, dtype=np.int64)
            counting_sort_order(keys, n_keys, order, self._counts)
        else:
            order = np.argsort(keys, kind="stable")
        p.permute(order)
        self.find_group_slices()
        self._needs_sort = False

    @property
    def needs_sort(self) -> bool:
        """Whether the next step must re-sort (particles arrived, left or changed group);
        saved in checkpoints so a restart sorts exactly when the uninterrupted run would."""
        return self._needs_sort

    def request_sort(self) -> None:
        """Particles changed rank or group: sort before the next step."""
        self._needs_sort = True

    def restore_order_state(self, needs_sort: bool) -> None:
        """After loading particles in their checkpointed order: resume the sort schedule.
        Without a pending sort the particles are still grouped, so the slices follow from
        the group column alone."""
        self._needs_sort = bool(needs_sort)
        if not self._needs_sort:
            self.find_group_slices()

    def ensure_grouped(self) -> None:
        """Sort now if a sort is pending (or none ran yet), so `group_slices` hold each
        material's particles; for work between steps (diagnostics, output)."""
        if self._needs_sort or not self.group_slices:
            self.sort_if_needed()

    def find_group_slices(self) -> None:
        """Each material's contiguous slice of the (group-sorted) particles."""
        bounds = np.searchsorted(self.particles["group"], np.arange(len(self.materials) + 1))
        self.group_slices = [(int(bounds[g]), int(bounds[g + 1]))
                             for g in range(len(self.materials))]

    def material_fields(self, g: int) -> dict[str, np.ndarray]:
        """Views of material ``g``'s particle rows."""
        start, stop = self.group_slices[g]
        p = self.particles
        return {name: p[name][start:stop] for name in p.field_names()}

    def scatter_stress(self, dt: float) -> None:
        """Stress and P2G, chunk by chunk within each on-grid material's slice.

        The material kernel writes a chunk's Kirchhoff stress into ``self._tau`` and P2G
        reads it while it is still in cache; no (n, d, d) stress field is kept."""
        p, grid, t = self.particles, self.grid, self.timers
        impulse = grid["impulse"] if self.split_force else grid["momentum"]
        arrays = {name: p[name] for name in p.field_names()}
        x, v, mass, vol0 = arrays["x"], arrays["v"], arrays["mass"], arrays["vol0"]
        C = arrays.get("C")
        if self.sync_phases:  # once: ranks run different numbers of chunks
            self.domain.barrier()
        for g in self._on_grid:
            material = self.materials[g]
            first, last = self.group_slices[g]
            for start in range(first, last, self.stress_chunk):
                stop = min(start + self.stress_chunk, last)
                tau = self._tau[: stop - start]
                with t("stress"):
                    fields = {name: a[start:stop] for name, a in arrays.items()}
                    fields["tau"] = tau
                    self.update_guarded(material, fields, start,
                                        lambda rows: material.update_stress(rows, dt),
                                        "its stress")
                for hook in self._stress_hooks:
                    with t("spb_energy"):
                        hook.stress_chunk(self, g, start, stop, tau, dt)
                with t("p2g"):
                    SCATTER[self.dim](
                        x[start:stop], v[start:stop],
                        self._dummy_C if C is None else C[start:stop], mass[start:stop],
                        vol0[start:stop], tau, self._static_scheme, self._static_order,
                        self.dinv_factor, self.dx, self.domain_lo, grid.origin, dt,
                        self._static_split, grid["mass"], grid["momentum"], impulse)
        if self.prescribed:
            with t("p2g"):
                self.scatter_prescribed_marks()

    def scatter_mass_momentum(self) -> None:
        """P2G of mass and momentum only (no stress): the semi-implicit step finds the
        stress impulse in its solve. The P2G kernel with dt = 0 and a zero stress adds none."""
        p, grid = self.particles, self.grid
        with self.phase("p2g"):
            if len(self._zero_tau) < p.n:
                self._zero_tau = np.zeros((p.capacity, self.dim, self.dim))
            impulse = grid["impulse"] if self.split_force else grid["momentum"]
            C = p["C"] if "C" in p else None
            ranges = self.grid_ranges()
            for start, stop in ranges:
                if stop > start:
                    SCATTER[self.dim](
                        p["x"][start:stop], p["v"][start:stop],
                        self._dummy_C if C is None else C[start:stop], p["mass"][start:stop],
                        p["vol0"][start:stop], self._zero_tau[: stop - start],
                        self._static_scheme, self._static_order, self.dinv_factor, self.dx,
                        self.domain_lo, grid.origin, 0.0, self._static_split, grid["mass"],
                        grid["momentum"], impulse)
            self.scatter_prescribed_marks()

    def grid_ranges(self) -> list[tuple[int, int]]:
        """The row ranges of the particles the grid carries (after the step's sort): all
        rows, or the on-grid materials' slices."""
        if self._all_on_grid:
            return [(0, self.particles.n)]
        return [self.group_slices[g] for g in self._on_grid]

    def scatter_prescribed_marks(self) -> None:
        """The prescribed sets' node marks (boundaries/prescribed.py) from the particles the
        grid carries: an off-grid PD particle of a set is moved by pd/boundary.py and has no
        nodes, so it must not clamp the nodes an MPM body beside it uses."""
        for clamp in self.prescribed:
            for start, stop in self.grid_ranges():
                clamp.scatter(self.particles, self.grid, self.order, start, stop)

    def scatter_forces(self, dt: float) -> None:
        """The force channel: per-particle forces of the step extensions (peridynamic bond
        forces of integral-based MPM, 003 eq. 5.2) reach the grid as ``dt sum_p w_ip f_p``."""
        if not self._force_sources:
            return
        grid = self.grid
        target = grid["impulse"] if self.split_force else grid["momentum"]
        x = self.particles["x"]
        for source in self._force_sources:
            with self.phase("forces"):
                pieces = list(source.particle_forces(self, dt))
            with self.phase("p2g_forces"):
                for start, stop, f in pieces:
                    SCATTER_FORCES[self.dim](
                        x[start:stop], np.ascontiguousarray(f, dtype=np.float64),
                        self._static_order, self.dx, self.domain_lo, grid.origin, dt, target)

    def kirchhoff_stress(self) -> np.ndarray:
        """The Kirchhoff stress of every particle (n, d, d), for output. Computed on copies
        of the material state, so nothing done here changes the run."""
        p = self.particles
        self.ensure_grouped()
        tau = np.zeros((p.n, self.dim, self.dim))
        for g, material in enumerate(self.materials):
            start, stop = self.group_slices[g]
            if stop > start:
                fields = {name: arr.copy() for name, arr in self.material_fields(g).items()}
                fields["tau"] = tau[start:stop]
                material.update_stress(fields, 0.0)
        return tau

    def update_grid(self, dt: float) -> None:
        """v_i = (p_i + dt f_i)/m_i + dt g, then walls, colliders and prescribed sets."""
        with self.phase("grid"):
            grid = self.grid
            d = self.dim
            flip = self.scheme == FLIP
            velocity = grid["velocity"]
            update_velocity(
                grid["mass"].reshape(-1), grid["momentum"].reshape(-1, d),
                (grid["impulse"] if self.split_force else grid["momentum"]).reshape(-1, d),
                self.split_force, self.gravity[:d], dt, velocity.reshape(-1, d),
                (grid["velocity_old"] if flip else velocity).reshape(-1, d), flip)
            self.apply_grid_boundaries(velocity, dt)

    def apply_grid_boundaries(self, velocity: np.ndarray, dt: float) -> None:
        """Walls and colliders, then prescribed sets (last: a clamp wins over the others),
        acting in place on a grid velocity field of the block."""
        grid = self.grid
        for condition in self.boundaries:
            condition.apply(velocity, grid.origin, self.dx, self.domain_lo, self.time, dt,
                            grid["mass"])
        for clamp in self.prescribed:
            clamp.apply(velocity, grid.origin, self.dx, self.domain_lo, self.time, dt, grid)

    def gather(self, dt: float, velocity: str = "velocity") -> None:
        """G2P from the grid field ``velocity``: v, C, x <- x + dt v, and F or J advanced
        (or L stored) per `deformation_mode`."""
        with self.phase("g2p"):
            p, grid = self.particles, self.grid
            old = grid["velocity_old"] if self.scheme == FLIP else self._dummy_vector
            C = p["C"] if "C" in p else None
            target = p[self.deformation]
            ranges = self.grid_ranges()
            for start, stop in ranges:
                if stop <= start:
                    continue
                deformation = target[start:stop]
                GATHER[self.dim](
                    p["x"][start:stop], p["v"][start:stop],
                    self._dummy_C if C is None else C[start:stop],
                    (deformation,) if self.deformation == "L" else deformation,
                    self._static_scheme, self._static_order, self.dinv_factor, self.dx,
                    self.domain_lo, grid.origin, dt, self.flip_alpha, grid[velocity], old)

    def update_states(self, dt: float) -> None:
        """After G2P: each material advances its state over ``dt`` (the F or b_E update
        from L in mode L, the plastic return map), so frames hold the projected state.
        Extensions' ``before_state`` first (SPB-MPM corrects F or L there)."""
        for extension in self._before_state:
            extension.before_state(self, dt)
        if not self._state_groups:
            return
        with self.phase("state"):
            for g in self._state_groups:
                start, stop = self.group_slices[g]
                if stop > start:
                    material = self.materials[g]
                    self.update_guarded(material, self.material_fields(g), start,
                                        lambda rows: material.update_state(rows, dt),
                                        "its state update")

    def update_guarded(self, material, fields, start: int, update, what: str) -> None:
        """``update(fields)``, a material kernel over rows ``start...`` of the particles.
        Where it divides by zero (a state already blown up: a singular or non-finite F; a
        fuzzed gravity of -1e308 gave snow's return map a ZeroDivisionError traceback on one
        rank), each row is evaluated alone, on a copy; those that divide by zero get a
        non-finite velocity, so the next health check, on every rank alike, stops the run
        with their ids, step and time, and the material's failure note names the cause. That
        runs once, as the run stops (SPB's PD stress does the same)."""
        try:
            update(fields)
            return
        except ZeroDivisionError:
            pass
        bad = np.zeros(len(fields["x"]), dtype=bool)
        for i in range(len(bad)):
            try:
                update({name: a[i:i + 1].copy() for name, a in fields.items()})
            except ZeroDivisionError:
                bad[i] = True
        self.particles["v"][start:start + len(bad)][bad] = np.nan
        if "tau" in fields:
            fields["tau"][bad] = 0.0
        material.failures.append(f"{what} divides by zero: a singular or non-finite "
                                 f"deformation gradient")

    def after_g2p(self, dt: float) -> None:
        for extension in self._after_g2p:
            extension.after_g2p(self, dt)

    # -- time step and health --------------------------------------------------------------
    def max_wave_speed(self) -> float:
        """Largest wave speed over the materials, agreed by all ranks: the rest values, or
        the particles' own where a model's speed depends on its state (a shock EOS)."""
        if not self._state_dependent_speed:
            return max((m.wave_speed() for m in self.materials), default=0.0)
        self.ensure_grouped()
        local = 0.0
        for g, m in enumerate(self.materials):
            start, stop = self.group_slices[g]
            local = max(local, m.wave_speed() if stop <= start
                        else m.max_wave_speed(self.material_fields(g)))
        return self.domain.max(local)

    def fastest_signal(self) -> str:
        """Where the step's bound comes from, for the message of a collapsed time step: the
        fastest particle (id, material, |v|) and, where a model's wave speed depends on its
        state, the particle with the largest wave speed, found by halving each material's
        slice (2 log2 n calls of `max_wave_speed`, about 2n particle visits: an error path,
        never a step's). Collective; the same text on every rank."""
        p = self.particles
        self.ensure_grouped()
        mine: list[tuple[float, int, str, str]] = []
        if p.n:
            speeds = np.linalg.norm(p["v"][: p.n], axis=1)
            i = int(np.argmax(speeds))
            mine.append((float(speeds[i]), int(p["id"][i]),
                         self.scene.materials[int(p["group"][i])].name, "speed |v|"))
        if self._state_dependent_speed:
            names = p.field_names()
            for g, m in enumerate(self.materials):
                lo, hi = self.group_slices[g]
                if hi <= lo or type(m).max_wave_speed is Material.max_wave_speed:
                    continue
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    left = m.max_wave_speed({k: p[k][lo:mid] for k in names})
                    right = m.max_wave_speed({k: p[k][mid:hi] for k in names})
                    lo, hi = (lo, mid) if left >= right else (mid, hi)
                c = m.max_wave_speed({k: p[k][lo:hi] for k in names})
                mine.append((float(c), int(p["id"][lo]), self.scene.materials[g].name,
                             "wave speed"))
        found = [r for part in self.domain.allgather(mine) for r in part]
        parts = []
        for what in ("speed |v|", "wave speed"):
            rows = [r for r in found if r[3] == what]
            if rows:
                value, pid, name, _ = max(rows, key=lambda r: (r[0], -r[1]))
                parts.append(f"the largest {what} is {value:.3g} at particle id {pid} "
                             f"(material {name!r})")
        return "; ".join(parts) if parts else "no particle is left"

    def stable_dt(self) -> float:
        """The integrator's stable time step (explicit: ``cfl dx / (c_max + |v|_max)``),
        agreed by all ranks; raises `InstabilityError` on every rank when any particle is
        broken."""
        speed = self.check_health()
        return self.integrator.stable_dt(self, speed)

    def check_health(self) -> float:
        """Global max particle speed; raises `InstabilityError` (same message on every rank)
        when a particle holds a non-finite value, det F <= 0 or J <= 0."""
        p = self.particles
        speed, nbad = self._scan_health()
        # One allreduce for the step's global decisions (speed, health, stop, far particles).
        speed, total_bad = self.domain.agree(p, speed, int(nbad))
        if self.domain.moved_in_agree:  # far jumps delivered: the order is stale
            self._needs_sort = True
        if total_bad:
            self.raise_instability(int(nbad), total_bad)
        return speed

    def _scan_health(self) -> tuple[float, int]:
        """This rank's largest particle speed and broken particles (`scan_health`; the
        first indices in ``self._bad``)."""
        p = self.particles
        kinds = [k for k in ("F", "J") if k in p] or ["mass"]  # mass > 0: only x, v checked
        lo, hi = self.health_bounds()
        speed, nbad = scan_health(p["x"], p["v"], p[kinds[0]], self._bad, MAX_REPORTED, lo, hi)
        if nbad == 0 and len(kinds) > 1:
            speed, nbad = scan_health(p["x"], p["v"], p[kinds[1]], self._bad, MAX_REPORTED,
                                      lo, hi)
        return speed, int(nbad)

    def assert_healthy(self) -> float:
        """`check_health` without its other decisions (no stop agreement, no delivery of
        far particles): before a checkpoint is written. A step's blow-up is otherwise found
        at the next step's check, after that step's checkpoint: measured, disks_2d at 50x
        its CFL step with a checkpoint every step wrote ckpt_000000005.h5 with the broken
        state the run then stopped on, and a restart (a requeued job takes the newest)
        failed on it at once. Returns the global largest particle speed."""
        speed, nbad = self._scan_health()
        maxes, sums = self.domain.max_then_sum([speed], [nbad])
        if sums[0]:
            self.raise_instability(nbad, int(sums[0]))
        return float(maxes[0])

    def health_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Where a particle may be: the domain widened on every side by its largest extent.
        Walls, colliders and periodic wraps keep particles within about a cell of the
        domain; one a whole domain size beyond it has blown up, even with finite values
        (measured: SPB probes flung particles to 1e5 m with finite x, v and det F > 0, and
        the next grid block asked for 374 GiB: a MemoryError traceback)."""
        lo = np.asarray(self.scene.domain_lo, dtype=np.float64)
        hi = np.asarray(self.scene.domain_hi, dtype=np.float64)
        reach = float(np.max(hi - lo))
        return lo - reach, hi + reach

    def raise_instability(self, nbad_local: int, total_bad: int) -> None:
        p = self.particles
        idx = self._bad[: min(nbad_local, MAX_REPORTED)]
        mine = [(int(p["id"][i]), self.scene.materials[int(p["group"][i])].name) for i in idx]
        messages = [msg for m in self.materials for msg in m.failures]
        gathered = self.domain.allgather((mine, messages))
        reports = sorted(r for rank_list, _ in gathered for r in rank_list)
        details = sorted({msg for _, msgs in gathered for msg in msgs})
        ids = ", ".join(str(i) for i, _ in reports[:MAX_REPORTED])
        names = sorted({name for _, name in reports})
        more = f" (and {total_bad - len(reports[:MAX_REPORTED])} more)" if total_bad > MAX_REPORTED else ""
        cause = f" ({'; '.join(details[:MAX_REPORTED])})" if details else ""
        if self.step_index == 0:
            # Nothing has been integrated yet: the scene's own values are out of range (a
            # speed of 1e299 m/s, whose square overflows; an axial-mode length of 1e-310,
            # whose sine is NaN), and a smaller time step would not help.
            hint = ("Hint: this is the initial state, before the first step: check the "
                    "velocity, velocity_field and material values of the bodies of these "
                    "materials (a speed whose square overflows counts as non-finite).")
        else:
            hint = (f"Hint: lower simulation.cfl (now {self.scene.cfl}) or a fixed "
                    f"simulation.dt, or refine simulation.dx (now {self.dx}).")
        raise InstabilityError(
            f"numerical instability at step {self.step_index}, t={self.time:.6g}: "
            f"{total_bad} particle(s) with a non-finite value or speed, det F <= 0 or a "
            f"position a domain size beyond the domain, ids {ids}{more}, "
            f"material {', '.join(repr(n) for n in names)}{cause}. {hint}")

    # -- diagnostics -----------------------------------------------------------------------
    def diagnostics(self) -> dict[str, float]:
        """Global mass, linear/angular momentum, kinetic, elastic and gravitational energy
        (-sum m g.x, zero at the origin), and their sum. Work done by walls, colliders,
        prescribed sets and forcing is not counted."""
        p = self.particles
        self.ensure_grouped()
        with_affine = self.scheme >= APIC
        inertia = self.dx * self.dx / self.dinv_factor
        local = np.zeros(10)
        local[0] = p["mass"].sum()
        local[1:8] = momentum_and_kinetic_energy(
            p["x"], p["v"], p["mass"], p["C"] if with_affine else self._dummy_C, with_affine,
            inertia)
        local[8] = sum(m.energy(self.material_fields(g)) for g, m in enumerate(self.materials)
                       if self.group_slices[g][1] > self.group_slices[g][0])
        # Energy held outside the particle fields (peridynamic bonds); collective.
        local[8] += sum(e.strain_energy(self) for e in self.extensions
                        if hasattr(e, "strain_energy"))
        g = self.gravity[:self.dim]
        if np.any(g != 0.0):
            local[9] = -float(p["mass"] @ (p["x"] @ g))
        total = self.domain.sum(local)
        out = {
            "mass": total[0],
            "momentum": total[1:4].copy(), "angular_momentum": total[4:7].copy(),
            "kinetic_energy": total[7], "elastic_energy": total[8],
            "gravity_energy": total[9], "total_energy": total[7] + total[8] + total[9],
        }
        # The integrator's own figures (semi-implicit: CG iterations per step since the
        # previous call, i.e. since the previous frame in a run); the same on every rank.
        report = getattr(self.integrator, "diagnostics", None)
        if report is not None:
            out.update(report())
        return out

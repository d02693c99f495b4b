"""Start-up at scale: count, check the memory, sample each rank's share, decompose.

Nothing here holds more than a rank's own particles (ARCHITECTURE.md "Start-up"): the bodies
are counted in chunks shared by the ranks (`hpcmpm.geometry.count_scene`), the memory a rank
will need is estimated from those counts and refused in one line when it cannot fit, then each
rank samples the ids ``[N r / P, N (r+1) / P)`` (whole lattice layers, so a slab of the last
axis) and the bisection moves them to their owners. ``hpcmpm run --dry-run`` stops there and
reports the counts and the measured peak memory of every rank.
"""

from __future__ import annotations

import logging
import os
import resource
from dataclasses import dataclass

import numpy as np

from .errors import SceneError

log = logging.getLogger(__name__)

# Resident size of a rank before it holds any particle: the interpreter, numpy, numba with
# the scene's kernels loaded from the cache, mpi4py, h5py (measured with `hpcmpm run
# --dry-run` on a 1000-particle scene: 215-235 MiB; rounded up).
BASE_BYTES = 256 * 2**20
# Transient bytes per particle on top of its fields at the peak of start-up and of a step:
# the migration after the bisection holds packed copies of the leavers and the arrivals
# (one row each, about the field bytes), the sort its keys and order (16 B); the particle
# arrays keep up to 50 % spare capacity. Calibrated against the measured dry-run peak
# (docs/parallel.md "Start-up"): 1.5 x fields + 16 B bounds it from above.
SPARE_FACTOR = 1.5
SCRATCH_BYTES = 16
# Sampling more particles at once than this only makes the temporaries bigger.
SAMPLE_BATCH = 1 << 18
# Particles a rank sends per round of the start-up migration (about 15 MiB of packed rows
# in 3D): the constant of the start-up memory instead of a second copy of the share.
MIGRATE_BATCH = 1 << 16


@dataclass
class MemoryEstimate:
    """What one rank needs at the peak of start-up and stepping."""

    particles: int            # in the whole scene
    ranks: int
    exact: bool               # the count is exact (counted) or from the shapes
    bytes_per_particle: int   # fields, spare capacity and scratch
    per_rank: int             # bytes on the busiest rank (within the rebalance threshold)
    side_per_rank: int = 0    # of which held outside the fields (peridynamic bonds)
    side_note: str = ""       # what the side bytes are, e.g. "36 half-bonds per particle"
    side_key: str = ""        # the scene key that sets them, e.g. "materials[0].horizon"
    grid_per_rank: int = 0    # of which the busiest rank's grid block (`grid_bytes`)

    def describe(self) -> str:
        about = "" if self.exact else "about "
        side = f" + {format_bytes(self.side_per_rank)} for {self.side_note}" \
            if self.side_per_rank else ""
        return (f"{about}{self.particles:,} particles, {format_bytes(self.per_rank)} per rank "
                f"on {self.ranks} rank(s) ({self.bytes_per_particle} B/particle{side} + "
                f"{format_bytes(BASE_BYTES)} per process)")


def counted(n: int, noun: str) -> str:
    """ "1 material", "2 materials"."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def format_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} TiB"


def particle_bytes(scene) -> int:
    """Bytes per particle at the peak: the fields the scene declares (materials, transfer,
    prescribed sets), the integrator's per-particle arrays (the semi-implicit solve's,
    `scratch_bytes_per_particle`) and volume averaging's copies of x and J, all allocated at
    the particles' capacity, hence with the spare factor, and the scratch of migration and
    sorting."""
    from .simulation import Simulation
    from .solvers import INTEGRATORS

    sim = Simulation(scene, None)
    fields = sim.particles.nbytes_per_particle()
    solver = INTEGRATORS[scene.integrator].scratch_bytes_per_particle(scene.dim)
    return int(SPARE_FACTOR * (fields + solver + sim.volume_scratch_bytes_per_particle())
               + SCRATCH_BYTES)


def side_bytes(scene, body_counts) -> tuple[float, str, str]:
    """Bytes held outside the particle fields (`Material.side_bytes_per_particle`: the
    peridynamic bonds, estimated from an interior family before anything is allocated) for
    ``body_counts`` particles per body. Returns (bytes, note, key) with the note and the
    scene key of the material that holds the most."""
    from .simulation import configured_materials

    materials = configured_materials(scene, scene.dim)
    per_material = np.zeros(len(materials))
    for body, count in zip(scene.bodies, body_counts):
        g = scene.material_index(body.material)
        per_material[g] += count * materials[g].side_bytes_per_particle()
    if not per_material.any():
        return 0.0, "", ""
    g = int(np.argmax(per_material))
    bonds = getattr(materials[g], "half_bonds_per_particle", None)
    what = f"{bonds()} half-bonds per particle" if bonds else "state outside the fields"
    return (float(per_material.sum()), f"{what} of {scene.materials[g].name!r}",
            f"materials[{g}].horizon" if bonds else f"materials[{g}]")


# Nodes a grid block holds per axis beyond the cells its particles fill: the support below
# and above (1 + 2, hpcmpm/parallel/domain.py), the cell itself, and the block's reuse margin
# on both sides (4 + 4, state.GridBlock).
BLOCK_EXTRA_NODES = 12


def grid_values_per_node(scene) -> int:
    """float64 values a grid node holds at most: the explicit step's mass, momentum and
    velocity (2 dim + 1) with room for the optional fields (split impulse, prescribed-set
    marks, volume averaging, SPB's energy and corrections: 5 dim + 2 in all); the
    semi-implicit solve's Newton and CG vectors besides (13 dim measured in 3D: 14 dim)."""
    d = scene.dim
    return 14 * d if scene.integrator == "semi_implicit" else 5 * d + 2


def grid_bytes(scene, count: int, ranks: int) -> float:
    """The busiest rank's grid block: the nodes of its share of the bodies' bounding box
    (each axis cut into ranks^(1/dim) pieces, plus `BLOCK_EXTRA_NODES`), or twice the cells
    its particles fill, whichever is more (a block is dense: the empty space between bodies
    on one rank is held too, and the whole period of a periodic axis where the bodies lie
    at one of its faces), times `grid_values_per_node`."""
    from .parallel.domain import GHOST_ABOVE, GHOST_BELOW
    from .scene import body_bounds
    from .simulation import configured_materials, grid_in_use

    if not grid_in_use(scene, configured_materials(scene, scene.dim)):
        return 0.0  # off-grid peridynamic bodies only: no block (Simulation.uses_grid)
    factor = scene.parallel.rebalance_threshold if ranks > 1 else 1.0
    cells = count / ranks * factor / scene.particles_per_cell ** scene.dim
    box = 0.0
    if scene.bodies:
        bounds = np.array([body_bounds(b.shape, b.params, scene.dim) for b in scene.bodies])
        lo = np.maximum(bounds[:, 0].min(axis=0), scene.domain_lo)
        hi = np.minimum(bounds[:, 1].max(axis=0), scene.domain_hi)
        # A periodic axis: particles within their support of a periodic face add to the
        # nodes at the other face, which a rank owning the whole axis holds in its one dense
        # block, so the block spans the period (measured: channel_bingham_2d with its
        # periodic x 1e9 times longer, the fluid still at x < 0.125, was estimated at
        # 258 MiB and its first step asked for 4.4 TiB). Counted for every rank count, as a
        # decomposition need not cut that axis.
        reach = (GHOST_BELOW + GHOST_ABOVE + 1) * scene.dx
        for axis, _ in scene.periods():
            if lo[axis] - scene.domain_lo[axis] < reach or \
                    scene.domain_hi[axis] - hi[axis] < reach:
                lo[axis], hi[axis] = scene.domain_lo[axis], scene.domain_hi[axis]
        pieces = ranks ** (1.0 / scene.dim)
        box = factor * float(np.prod(np.ceil(np.maximum(hi - lo, 0.0) / scene.dx / pieces)
                                     + BLOCK_EXTRA_NODES))
    return 8.0 * grid_values_per_node(scene) * max(2.0 * cells, box)


def shared_body_counts(scene, count: int, body_counts=None):
    """``body_counts``, or ``count`` shared among the bodies as their shapes estimate."""
    if body_counts is not None:
        return body_counts
    from .geometry import estimate_body_counts

    guess, _ = estimate_body_counts(scene)
    return np.asarray(guess) * (count / max(sum(guess), 1.0))


def estimate_memory(scene, count: int, ranks: int, exact: bool,
                    body_counts=None) -> MemoryEstimate:
    """Bytes per rank for ``count`` particles on ``ranks`` ranks. The busiest rank may hold
    up to ``parallel.rebalance_threshold`` times the mean before a rebalance; the grid block
    (`grid_bytes`) is included, and so are the bonds of peridynamic bodies (`side_bytes`;
    ``body_counts``: the particles of each body, by default ``count`` shared as the bodies'
    shapes estimate)."""
    side = side_bytes(scene, shared_body_counts(scene, count, body_counts))
    return _estimate_on(scene, count, ranks, exact, particle_bytes(scene), side)


def _estimate_on(scene, count: int, ranks: int, exact: bool, per_particle: int,
                 side: tuple[float, str, str]) -> MemoryEstimate:
    """`estimate_memory` from the parts that do not depend on the rank count: the bytes
    per particle and the side bytes of the whole scene (`side_bytes`)."""
    factor = scene.parallel.rebalance_threshold if ranks > 1 else 1.0
    share = count / ranks * factor
    grid = grid_bytes(scene, count, ranks)
    side, note, key = side
    side_share = int(side / ranks * factor)
    per_rank = int(share * per_particle + grid + side_share + BASE_BYTES)
    return MemoryEstimate(int(count), ranks, exact, per_particle, per_rank, side_share, note,
                          key, int(grid))


def available_memory() -> int | None:
    """Bytes this node can still give: ``MemAvailable`` of /proc/meminfo, capped by the
    cgroup limit of a batch job (cgroup v2 ``memory.max`` minus ``memory.current``).
    None where neither can be read (then nothing is refused)."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
    except OSError:
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            limit = f.read().strip()
        with open("/sys/fs/cgroup/memory.current") as f:
            current = int(f.read().strip())
        if limit != "max":
            found.append(int(limit) - current)
    except (OSError, ValueError):
        pass
    return min(found) if found else None


def ranks_needed(scene, estimate: MemoryEstimate, per_rank_here: float,
                 body_counts=None) -> int | None:
    """The fewest ranks whose busiest one (`estimate_memory` on that many ranks) fits in
    ``per_rank_here`` bytes, or None when no rank count below 2^40 does. Searched, not scaled
    from this estimate: on more ranks the busiest one holds up to the rebalance factor above
    the mean (which a 1-rank estimate leaves out) and the grid block shrinks more slowly than
    the share (`grid_bytes`); both are non-increasing beyond 2 ranks, so a bisection finds
    the least count."""
    # Built once: the bytes per particle build a Simulation, whose peridynamic materials sum
    # their lattice families (a horizon of 256 spacings in 3D: 2.5 s a time, 16 times).
    side = side_bytes(scene, shared_body_counts(scene, estimate.particles, body_counts))

    def fits(ranks: int) -> bool:
        return _estimate_on(scene, estimate.particles, ranks, estimate.exact,
                            estimate.bytes_per_particle, side).per_rank <= per_rank_here

    lo, hi = estimate.ranks, max(2 * estimate.ranks, 2)   # lo does not fit
    while not fits(hi):
        lo, hi = hi, 2 * hi
        if hi > 2 ** 40:
            return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def memory_problem(scene, estimate: MemoryEstimate, ranks_on_node: int,
                   available: int | None, body_counts=None) -> str | None:
    """The one-line refusal when ``ranks_on_node`` ranks of this estimate do not fit in
    ``available`` bytes, else None; it names the rank count that would fit (`ranks_needed`,
    as many ranks per node; ``body_counts`` as for `estimate_memory`)."""
    if available is None or estimate.per_rank * ranks_on_node <= available:
        return None
    per_rank_here = available / ranks_on_node
    needed = ranks_needed(scene, estimate, per_rank_here, body_counts)
    key, lower = "simulation.particles_per_cell", \
        "lower simulation.particles_per_cell or refine less"
    if 2 * estimate.side_per_rank > estimate.per_rank - BASE_BYTES:   # mostly bonds
        key, lower = estimate.side_key, f"lower {estimate.side_key}"
    elif 2 * estimate.grid_per_rank > estimate.per_rank - BASE_BYTES:  # mostly the grid
        key, lower = "simulation.dx", (
            f"coarsen simulation.dx, or bring the bodies closer together and away from "
            f"periodic faces: of it, {format_bytes(estimate.grid_per_rank)} is a rank's dense "
            f"grid block, which spans the space between its bodies and a whole periodic axis "
            f"where a body lies at its face")
    hint = (f"run on at least {needed} ranks with {ranks_on_node} per node like this one, "
            if needed else "") + "or " + lower
    return (f"{scene.path}: {key}: the scene needs "
            f"{estimate.describe()}, but this node has {format_bytes(available)} available "
            f"for {ranks_on_node} rank(s) ({format_bytes(per_rank_here)} each): {hint}")


def check_memory(scene, domain, count: int, exact: bool, body_counts=None) -> MemoryEstimate:
    """Estimate and refuse together: every rank raises the same `SceneError` when any node
    cannot hold its ranks' shares (one max-reduction)."""
    estimate = estimate_memory(scene, count, domain.size, exact, body_counts)
    available = available_memory()
    local = domain.ranks_on_node()
    ratio = estimate.per_rank * local / available if available else 0.0
    worst = domain.max(ratio)
    if worst > 1.0:
        # The node with the least room reports; everybody raises its line.
        line = memory_problem(scene, estimate, local, available, body_counts) \
            if ratio == worst else None
        lines = [x for x in domain.allgather(line) if x]
        raise SceneError(lines[0])
    return estimate


def initial_particles(sim) -> MemoryEstimate:
    """Count, check, sample this rank's share, mark prescribed particles, decompose."""
    from .geometry import (count_overlaps, count_scene, estimate_body_counts, overlap_warning,
                           sample_share, share_bounds)

    scene, domain, p = sim.scene, sim.domain, sim.particles
    # The shapes first: a scene far too big is refused before every lattice point is tested
    # (a fuzzed particles_per_cell of 1000 on watermelon_3d counted 3.4e12 points for hours).
    # The bodies' estimates go along, so the bond bytes do not sample the meshes again.
    guesses, exact = estimate_body_counts(scene)
    check_memory(scene, domain, int(round(sum(guesses))), exact, guesses)
    counts = count_scene(scene, domain.rank, domain.size, domain.sum)
    warning = overlap_warning(scene, count_overlaps(scene, counts.lattices, domain.rank,
                                                    domain.size, domain.sum))
    if warning and domain.rank == 0:
        log.warning("%s", warning)
    estimate = check_memory(scene, domain, counts.total, True,
                            [counts.body_count(b) for b in range(len(scene.bodies))])
    start, stop = share_bounds(counts.total, domain.rank, domain.size)
    # Room for the share and for what the bisection may give beyond it (a slab of cells),
    # so that the arrivals do not make the arrays grow by half.
    share = stop - start
    p.reserve(p.n + share + (share // 16 + MIGRATE_BATCH if domain.size > 1 else 0))
    for a in range(start, stop, SAMPLE_BATCH):
        values = sample_share(scene, counts, a, min(a + SAMPLE_BATCH, stop))
        p.append({k: v for k, v in values.items() if k in p})
        del values
    if scene.prescribed:
        from .boundaries import mark_prescribed_particles

        mark_prescribed_particles(scene, p)
    # Most particles change rank here (a slab of lattice layers is not a bisection box):
    # moved in rounds, so the buffers in flight stay at MIGRATE_BATCH rows.
    domain.decompose(p, batch=MIGRATE_BATCH, weights=sim.load_weights())
    return estimate


def peak_rss_bytes() -> int:
    """Peak resident size of this process so far (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def dry_run(scene, comm) -> int:
    """`hpcmpm run --dry-run`: sample, decompose, report counts and memory per rank, exit."""
    from .parallel import make_domain
    from .simulation import Simulation

    domain = make_domain(scene, comm)
    domain.install_abort_hook()
    sim = Simulation(scene, domain)
    estimate = initial_particles(sim)
    counts = np.asarray(domain.allgather(int(sim.particles.n)), dtype=np.int64)
    # With PD bonds the ranks are balanced by weight, not by count (Simulation.load_weights).
    weights = sim.load_weights()
    loads = None if weights is None else \
        np.asarray(domain.allgather(int(weights.sum())), dtype=np.int64)
    rss = np.asarray(domain.allgather(peak_rss_bytes()), dtype=np.int64)
    if domain.rank == 0:
        by_weight = "" if loads is None else \
            f"; by load weight {loads.max() / max(loads.mean(), 1):.3f}"
        print(f"{scene.path}: dry run on {domain.size} rank(s): {int(counts.sum()):,} "
              f"particles, per rank min {counts.min():,} / max {counts.max():,} "
              f"(imbalance {counts.max() / max(counts.mean(), 1):.3f}{by_weight})")
        print(f"memory estimate: {estimate.describe()}")
        print(f"peak RSS per rank (start-up): max {format_bytes(rss.max())}, "
              f"min {format_bytes(rss.min())}, mean {format_bytes(rss.mean())}; "
              f"per rank [MiB]: {' '.join(str(int(r / 2**20)) for r in rss)}")
        if os.environ.get("HPCMPM_DRY_RUN_JSON"):
            import json

            with open(os.environ["HPCMPM_DRY_RUN_JSON"], "w") as f:
                json.dump({"ranks": domain.size, "particles": int(counts.sum()),
                           "counts": counts.tolist(), "peak_rss": rss.tolist(),
                           "estimate_per_rank": estimate.per_rank,
                           "bytes_per_particle": estimate.bytes_per_particle}, f)
    return 0


# Counting tests every lattice point of a non-box body; `hpcmpm validate` counts exactly up
# to this many (a few seconds on one core) and estimates from the shapes beyond.
VALIDATE_COUNT_LIMIT = 50_000_000


def validate_report(scene) -> str:
    """The line `hpcmpm validate` prints: particle count and the memory estimate on one rank
    against this machine's available memory (with the rank count that would fit), then the
    materials' notes (`Material.notes`: e.g. bond plasticity's yield stretch)."""
    from .geometry import body_lattice, count_overlaps, count_scene, estimate_body_counts, \
        overlap_warning
    from .simulation import configured_materials

    lattice_points = sum(body_lattice(b, scene).size for b in scene.bodies
                         if b.shape != "box")
    body_counts, warning = None, None
    if lattice_points <= VALIDATE_COUNT_LIMIT:
        counts = count_scene(scene)
        count, exact = counts.total, True
        body_counts = [counts.body_count(b) for b in range(len(scene.bodies))]
        warning = overlap_warning(scene, count_overlaps(scene, counts.lattices))
    else:
        body_counts, exact = estimate_body_counts(scene)
        count = int(round(sum(body_counts)))
    estimate = estimate_memory(scene, count, 1, exact, body_counts)
    available = available_memory()
    notes = "".join(f"\n{scene.path}: {line}" for material in
                    configured_materials(scene, scene.dim) for line in material.notes())
    head = (f"{scene.path}: ok ({'' if exact else 'about '}{counted(count, 'particle')}, "
            f"{counted(len(scene.materials), 'material')}, dim {scene.dim})")
    if warning:
        head = f"{head}\n{warning}"
    memory = f"{scene.path}: memory estimate: {estimate.describe()}"
    if available is None:
        return f"{head}\n{memory}{notes}"
    problem = memory_problem(scene, estimate, 1, available, body_counts)
    if problem:
        return f"{head}\n{problem}"
    return f"{head}\n{memory}; {format_bytes(available)} available here{notes}"

"""Samplers that turn a scene's bodies into particles, one rank's share at a time.

Particles sit on a regular lattice of ``particles_per_cell`` points per axis per cell, at the
cell-relative offsets ``(k + 1/2) / ppc``, aligned to the global grid so that touching bodies
tile without gaps or overlaps; each carries the volume ``(dx / ppc)^dim``.

**Lattice order and ids.** A body's lattice points (the lattice inside its bounding box) are
numbered with axis 0 fastest and the last axis slowest (a *layer* is one index of the last
axis). Its particles are the points inside the body, in that order; the ids run ``0 .. N-1``
over the bodies in scene order. Whole x-lines stay together, which keeps the mesh scanline
test (one pass over the triangles per line) efficient in chunks.

**Per-rank sampling** (`count_scene`, `share_bounds`, `sample_share`): first the exact number
of inside points per layer, counted in chunks of `CHUNK` lattice points that the ranks share
round-robin, then one sum-reduction; boxes are counted without a test. No particle is kept
while counting (memory: one chunk). Rank ``r`` of ``P`` then samples the ids
``[N r / P, N (r+1) / P)``: the layers holding them, chunk by chunk, keeping only its points.
The ids come from the counts' prefix sum, so they do not depend on the rank count, and
neither does anything else: jitter is drawn from the body's PCG64 stream advanced to the
first point (the numbers a one-rank run draws for it), and the centroid of a spinning body
is the sum of per-chunk sums over the lattice points, added in chunk order on every rank.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SceneError
from ..scene import Scene, body_bounds
from .mesh import inside_mesh

# Lattice points per inside test: bounds the temporaries of counting and sampling (about
# 100 B per point in 3D: coordinates, indices, mask) independently of the body size.
CHUNK = 1 << 18


def lattice_axes(lower, upper, domain_lo, spacing: float,
                 closed: bool = False) -> list[np.ndarray]:
    """Lattice coordinates ``domain_lo + (k + 1/2) spacing`` per axis in [lower, upper).

    Half-open so that two bodies sharing a face never both take (or both miss) a point that
    lies exactly on it; the integer range decides membership, not a float comparison. With
    ``closed``, [lower, upper]: the bounding box of a body whose own inside test is closed
    (sphere, cylinder) must not drop the points on its upper extremes, which are inside."""
    axes = []
    for lo, hi, origin in zip(lower, upper, domain_lo):
        k0 = int(np.ceil((lo - origin) / spacing - 0.5))
        k1 = int(np.floor((hi - origin) / spacing - 0.5)) + 1 if closed else \
            int(np.ceil((hi - origin) / spacing - 0.5))
        axes.append(origin + (np.arange(k0, max(k0, k1)) + 0.5) * spacing)
    return axes


def lattice(lower, upper, domain_lo, spacing: float) -> np.ndarray:
    """All lattice points in the half-open box [lower, upper), in lattice order (n, dim)."""
    lat = BodyLattice(lattice_axes(lower, upper, domain_lo, spacing), solid=True)
    return lat.points(0, lat.size)


def inside(body, x: np.ndarray, dim: int) -> np.ndarray:
    p = body.params
    if body.shape == "box":
        return np.ones(len(x), dtype=np.bool_)  # the lattice of its bounds is the box
    if body.shape == "sphere":
        return np.sum((x - np.asarray(p["center"])) ** 2, axis=1) <= p["radius"] ** 2
    if body.shape == "cylinder":
        a = np.asarray(p["axis"], dtype=np.float64)
        a = a / np.linalg.norm(a)
        r = x - np.asarray(p["center"])
        along = r @ a
        radial = np.sum(r * r, axis=1) - along ** 2
        return (np.abs(along) <= p["length"] / 2) & (radial <= p["radius"] ** 2)
    return inside_mesh(x, p, dim)


class BodyLattice:
    """The lattice points of a body's bounding box, numbered in lattice order."""

    def __init__(self, axes: list[np.ndarray], solid: bool):
        self.axes = axes
        self.solid = solid  # every point is inside (a box): no inside test
        self.shape = tuple(len(a) for a in axes)
        self.size = int(np.prod(self.shape))
        self.layer_size = int(np.prod(self.shape[:-1]))
        self.n_layers = self.shape[-1]

    def points(self, g0: int, g1: int) -> np.ndarray:
        """Coordinates (g1 - g0, dim) of the lattice points g0 .. g1-1."""
        rest = np.arange(g0, g1, dtype=np.int64)
        x = np.empty((g1 - g0, len(self.axes)))
        for a, coords in enumerate(self.axes):
            rest, k = np.divmod(rest, self.shape[a])
            x[:, a] = coords[k]
        return x


# Beyond these a scene is a typo, not a run (2**31 particles along a line; 2**53, where the
# float64 counts and estimates stop being exact), and the lattice axes alone might not fit in
# memory: `body_lattice` refuses them before allocating anything.
MAX_AXIS_POINTS = 2**31
MAX_LATTICE_POINTS = 2**53


def lattice_shape(lower, upper, domain_lo, spacing: float,
                  closed: bool = False) -> list[float]:
    """Points per axis of `lattice_axes`, computed in floats (inf when they overflow), without
    allocating anything."""
    shape = []
    for lo, hi, origin in zip(lower, upper, domain_lo):
        a, b = (lo - origin) / spacing - 0.5, (hi - origin) / spacing - 0.5
        if not (math.isfinite(a) and math.isfinite(b)):
            shape.append(math.inf)
            continue
        end = math.floor(b) + 1 if closed else math.ceil(b)
        shape.append(max(end - math.ceil(a), 0))
    return shape


def body_lattice(body, scene: Scene) -> BodyLattice:
    lower, upper = body_bounds(body.shape, body.params, scene.dim)
    spacing = scene.dx / scene.particles_per_cell
    # The inside tests of spheres and cylinders are closed (`inside`): so is their lattice.
    closed = body.shape in ("sphere", "cylinder")
    shape = lattice_shape(lower, upper, scene.domain_lo, spacing, closed)
    total = math.prod(float(n) for n in shape)
    if max(shape) > MAX_AXIS_POINTS or total > MAX_LATTICE_POINTS:
        raise SceneError(
            f"{scene.path}: simulation.particles_per_cell: bodies[{scene.bodies.index(body)}] "
            f"would take {total:.3g} lattice points ({float(max(shape)):.3g} along one axis) "
            f"at the particle spacing dx / particles_per_cell = {spacing:g}, more than any "
            f"run can hold; use a larger simulation.dx or fewer particles_per_cell")
    return BodyLattice(lattice_axes(lower, upper, scene.domain_lo, spacing, closed),
                       solid=body.shape == "box")


@dataclass
class SceneCounts:
    """Exact particle counts of a scene's bodies, known on every rank before sampling."""

    lattices: list[BodyLattice]
    layer_counts: list[np.ndarray]  # per body: inside points per layer, (n_layers,) int64
    centroids: list[np.ndarray]     # per body: mean of its lattice points inside, (dim,)
    offsets: np.ndarray             # (n_bodies + 1,): first id of each body, then the total

    @property
    def total(self) -> int:
        return int(self.offsets[-1])

    def body_count(self, b: int) -> int:
        return int(self.offsets[b + 1] - self.offsets[b])


def count_scene(scene: Scene, rank: int = 0, size: int = 1, reduce_sum=None) -> SceneCounts:
    """Exact inside points per layer of every body and each body's centroid, without keeping
    any particle: rank ``rank`` of ``size`` tests the chunks ``c = rank, rank + size, ...``,
    then ``reduce_sum`` (an elementwise sum over ranks of a numpy array; identity on one rank)
    combines them in two reductions. Every rank calls it with the same scene; all get the
    same result. Raises `SceneError` for a body that holds no particle."""
    reduce_sum = reduce_sum or (lambda a: a)
    lattices = [body_lattice(body, scene) for body in scene.bodies]
    layer_counts, chunk_sums = [], []
    for body, lat in zip(scene.bodies, lattices):
        n_chunks = -(-lat.size // CHUNK)
        if lat.solid:
            layer_counts.append(np.full(lat.n_layers, lat.layer_size, dtype=np.int64))
            chunk_sums.append(None)
            continue
        counts = np.zeros(lat.n_layers, dtype=np.int64)
        sums = np.zeros((n_chunks, scene.dim))
        for c in range(rank, n_chunks, size):
            g0, g1 = c * CHUNK, min((c + 1) * CHUNK, lat.size)
            x = lat.points(g0, g1)
            mask = inside(body, x, scene.dim)
            index = np.flatnonzero(mask)
            counts += np.bincount((index + g0) // lat.layer_size, minlength=lat.n_layers)
            sums[c] = x[index].sum(axis=0)
        layer_counts.append(counts)
        chunk_sums.append(sums)
    tested = [b for b, lat in enumerate(lattices) if not lat.solid]
    if tested:
        # Each entry has one contributor, so the sums are exact and the same on every rank
        # count; the centroids then add the chunk sums in chunk order.
        all_counts = reduce_sum(np.concatenate([layer_counts[b] for b in tested]))
        all_sums = reduce_sum(np.concatenate([chunk_sums[b] for b in tested]))
        start = start_sums = 0
        for b in tested:
            n, m = lattices[b].n_layers, len(chunk_sums[b])
            layer_counts[b] = all_counts[start:start + n]
            chunk_sums[b] = all_sums[start_sums:start_sums + m]
            start, start_sums = start + n, start_sums + m
    totals = np.array([int(c.sum()) for c in layer_counts], dtype=np.int64)
    for b, n in enumerate(totals):
        if n == 0:
            raise SceneError(f"{scene.path}: bodies[{b}]: holds no particles (smaller than "
                             f"the particle spacing dx / particles_per_cell = "
                             f"{scene.dx / scene.particles_per_cell:g}?)")
    centroids = [np.array([a.mean() for a in lat.axes]) if lat.solid
                 else chunk_sums[b].sum(axis=0) / totals[b] for b, lat in enumerate(lattices)]
    offsets = np.concatenate([[0], np.cumsum(totals)]).astype(np.int64)
    return SceneCounts(lattices, layer_counts, centroids, offsets)


def _lattice_index_range(axis: np.ndarray, origin: float, spacing: float) -> tuple[int, int]:
    """The global lattice indices ``[k0, k1)`` of one axis of a body's lattice."""
    if len(axis) == 0:
        return 0, 0
    k0 = int(round((axis[0] - origin) / spacing - 0.5))
    return k0, k0 + len(axis)


def count_overlaps(scene: Scene, lattices: list[BodyLattice], rank: int = 0, size: int = 1,
                   reduce_sum=None) -> list[tuple[int, int, int]]:
    """Lattice points that two bodies both fill: ``(i, j, n)`` per pair with ``n > 0``.

    Every body samples the one global lattice, so bodies that overlap take the same points
    twice and their mass counts twice there (two particles at one place, each with the full
    volume). Only the lattice common to both bounding boxes is tested, in chunks that the
    ranks share round-robin, then one sum-reduction (collective when ``size > 1``); bodies that
    touch along a face share no point (the lattices are half-open)."""
    reduce_sum = reduce_sum or (lambda a: a)
    spacing = scene.dx / scene.particles_per_cell
    pairs, boxes = [], []
    for i in range(len(lattices)):
        for j in range(i + 1, len(lattices)):
            ranges = [(max(a0, b0), min(a1, b1)) for (a0, a1), (b0, b1) in zip(
                (_lattice_index_range(ax, o, spacing)
                 for ax, o in zip(lattices[i].axes, scene.domain_lo)),
                (_lattice_index_range(ax, o, spacing)
                 for ax, o in zip(lattices[j].axes, scene.domain_lo)))]
            if all(k1 > k0 for k0, k1 in ranges):
                pairs.append((i, j))
                boxes.append(BodyLattice([o + (np.arange(k0, k1) + 0.5) * spacing
                                          for (k0, k1), o in zip(ranges, scene.domain_lo)],
                                         solid=False))
    if not pairs:
        return []
    counts = np.zeros(len(pairs), dtype=np.int64)
    chunk = 0  # numbered over all pairs, so the ranks share the work whatever the pair sizes
    for p, ((i, j), box) in enumerate(zip(pairs, boxes)):
        if lattices[i].solid and lattices[j].solid:
            counts[p] = box.size * (rank == 0)  # two boxes: their common box, no test
            continue
        for g0 in range(0, box.size, CHUNK):
            if chunk % size == rank:
                x = box.points(g0, min(g0 + CHUNK, box.size))
                both = inside(scene.bodies[i], x, scene.dim) & inside(scene.bodies[j], x,
                                                                      scene.dim)
                counts[p] += int(np.count_nonzero(both))
            chunk += 1
    counts = reduce_sum(counts)
    return [(i, j, int(n)) for (i, j), n in zip(pairs, counts) if n > 0]


def overlap_warning(scene: Scene, overlaps: list[tuple[int, int, int]]) -> str | None:
    """The line that reports overlapping bodies, or None."""
    if not overlaps:
        return None
    names = [body.name for body in scene.bodies]
    what = "; ".join(f"bodies[{i}] ({names[i]!r}) and bodies[{j}] ({names[j]!r}) share "
                     f"{n:,} lattice point(s)" for i, j, n in overlaps)
    return (f"{scene.path}: warning: bodies overlap ({what}): each body puts a particle on "
            f"every lattice point it covers, so the mass and volume there count twice; make "
            f"the bodies disjoint (touching faces share no point)")


def estimate_count(scene: Scene) -> tuple[int, bool]:
    """Particle count from the bodies' shapes, without testing every point: exact for boxes,
    volume / spacing^dim for spheres and cylinders, and for meshes the bounding lattice times
    the fraction of a sub-lattice of it inside (`mesh_inside_fraction`; exact where that
    sub-lattice is the lattice). Returns (count, exact)."""
    counts, exact = estimate_body_counts(scene)
    return int(round(sum(counts))), exact


def estimate_body_counts(scene: Scene) -> tuple[list[float], bool]:
    """`estimate_count` per body: (counts, all exact)."""
    spacing = scene.dx / scene.particles_per_cell
    out, exact = [], True
    for body in scene.bodies:
        lat = body_lattice(body, scene)
        p = body.params
        if body.shape == "sphere":
            volume = np.pi * p["radius"] ** 2 if scene.dim == 2 else \
                4.0 / 3.0 * np.pi * p["radius"] ** 3
            out.append(min(volume / np.float64(spacing) ** scene.dim, lat.size))
            exact = False
        elif body.shape == "cylinder":
            out.append(min(np.pi * p["radius"] ** 2 * p["length"] / np.float64(spacing) ** 3, lat.size))
            exact = False
        elif body.shape == "mesh":
            fraction, sampled_all = mesh_inside_fraction(body, scene, lat)
            out.append(fraction * lat.size)
            exact = exact and sampled_all
        else:
            out.append(float(lat.size))
    return out, exact


# A mesh body's count estimate tests at most about this many points of its lattice: well
# under a second for the shipped meshes (measured: 0.11-0.15 s for watermelon_3d's two
# surface meshes and its sphere, 0.02-0.07 s for taylor_cu_3d's bar).
MESH_SAMPLE_POINTS = 100_000


def mesh_inside_fraction(body, scene: Scene, lat: BodyLattice) -> tuple[float, bool]:
    """The fraction of a mesh body's lattice points inside it, from every k-th point along
    each axis (k the smallest that keeps the sample within `MESH_SAMPLE_POINTS`), and whether
    that was every point (k = 1). A mesh fills its bounding box anywhere from nearly all to a
    small part of it, so its bounding lattice alone can overstate the count many times (a
    fuzzed particles_per_cell of 1000 on watermelon_3d: 3.4e12 lattice points); the sample's
    error is its boundary layer, about 1 / k^(d-1) of the surface's points."""
    if lat.size == 0:
        return 0.0, True
    k = max(1, math.ceil((lat.size / MESH_SAMPLE_POINTS) ** (1.0 / scene.dim)))
    sample = BodyLattice([a[min(k // 2, len(a) - 1)::k] for a in lat.axes], solid=False)
    x = sample.points(0, sample.size)
    return float(np.count_nonzero(inside(body, x, scene.dim))) / sample.size, k == 1


def share_bounds(total: int, rank: int, size: int) -> tuple[int, int]:
    """The ids ``[start, stop)`` rank ``rank`` of ``size`` samples: equal shares in id order."""
    return total * rank // size, total * (rank + 1) // size


def sample_body_range(body, scene: Scene, lat: BodyLattice, layer_counts: np.ndarray,
                      a: int, b: int) -> np.ndarray:
    """Positions (b - a, dim) of the body's particles a .. b-1 (in lattice order), jittered.

    Tests only the layers that hold them, a chunk at a time, keeping just the wanted points."""
    out = np.empty((b - a, scene.dim))
    if b <= a:
        return out
    if lat.solid:
        for g in range(a, b, CHUNK):
            out[g - a:min(g + CHUNK, b) - a] = lat.points(g, min(g + CHUNK, b))
    else:
        cum = np.cumsum(layer_counts)
        k0 = int(np.searchsorted(cum, a, side="right"))
        k1 = int(np.searchsorted(cum, b - 1, side="right"))
        seen = int(cum[k0 - 1]) if k0 else 0  # body index of the next inside point
        filled = 0
        for g in range(k0 * lat.layer_size, (k1 + 1) * lat.layer_size, CHUNK):
            x = lat.points(g, min(g + CHUNK, (k1 + 1) * lat.layer_size))
            x = x[inside(body, x, scene.dim)]
            lo, hi = max(a - seen, 0), min(b - seen, len(x))
            if hi > lo:
                out[filled:filled + hi - lo] = x[lo:hi]
                filled += hi - lo
            seen += len(x)
            if seen >= b:
                break
    if body.jitter > 0:
        spacing = scene.dx / scene.particles_per_cell
        rng = np.random.Generator(np.random.PCG64(body.seed))
        rng.bit_generator.advance(a * scene.dim)  # one 64-bit draw per coordinate
        out += rng.uniform(-0.5, 0.5, size=out.shape) * body.jitter * spacing
    return out


def sample_body(body, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, dim) and volumes (n,) of the particles filling ``body`` (one process)."""
    b = scene.bodies.index(body)
    counts = count_scene(scene)
    n = counts.body_count(b)
    spacing = scene.dx / scene.particles_per_cell
    x = sample_body_range(body, scene, counts.lattices[b], counts.layer_counts[b], 0, n)
    return x, np.full(n, spacing ** scene.dim)


def initial_velocity(body, x: np.ndarray, dim: int, centroid: np.ndarray) -> np.ndarray:
    """Body velocity plus rigid spin about the body's centroid, plus an optional field."""
    v = np.tile(np.asarray(body.velocity, dtype=np.float64), (len(x), 1))
    if len(x) == 0:
        return v
    r = x - centroid
    w = body.angular_velocity
    # Values out of range (an angular velocity of 1e308, an axial-mode length of 1e-310)
    # give inf or NaN velocities: the run's first health check reports them as the initial
    # state's, with the particles' ids and materials.
    if dim == 2:
        v += float(w) * np.stack([-r[:, 1], r[:, 0]], axis=1)
    else:
        v += np.cross(np.asarray(w, dtype=np.float64), r)
    f = body.velocity_field
    if f is not None and f["type"] == "axial_mode":
        # First axial mode of a bar fixed at 0 and free at L: v = A sin(pi x / 2L).
        v[:, f["axis"]] += f["amplitude"] * np.sin(np.pi * x[:, f["axis"]] / (2 * f["length"]))
    return v


def sample_share(scene: Scene, counts: SceneCounts, start: int, stop: int) -> dict:
    """Particles with ids ``[start, stop)``: x, v, mass, vol0, group (material index), id."""
    spacing = scene.dx / scene.particles_per_cell
    vol = spacing ** scene.dim
    parts = []
    for b, body in enumerate(scene.bodies):
        a, e = max(start, counts.offsets[b]), min(stop, counts.offsets[b + 1])
        if e <= a:
            continue
        first = int(counts.offsets[b])
        x = sample_body_range(body, scene, counts.lattices[b], counts.layer_counts[b],
                              int(a - first), int(e - first))
        group = scene.material_index(body.material)
        density = scene.materials[group].density
        parts.append({"x": x, "v": initial_velocity(body, x, scene.dim, counts.centroids[b]),
                      "mass": np.full(len(x), density * vol), "vol0": np.full(len(x), vol),
                      "group": np.full(len(x), group, dtype=np.int32),
                      "id": np.arange(a, e, dtype=np.int64)})
    if not parts:
        return {"x": np.empty((0, scene.dim)), "v": np.empty((0, scene.dim)),
                "mass": np.empty(0), "vol0": np.empty(0), "group": np.empty(0, np.int32),
                "id": np.empty(0, np.int64)}
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def sample_scene(scene: Scene) -> dict[str, np.ndarray]:
    """Every body's particles in one process: x, v, mass, vol0, group, id (0..N-1)."""
    counts = count_scene(scene)
    return sample_share(scene, counts, 0, counts.total)

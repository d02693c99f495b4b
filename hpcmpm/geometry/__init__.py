"""Samplers that turn a scene's bodies into particles.

Particles sit on a regular lattice of ``particles_per_cell`` points per axis per cell, at the
cell-relative offsets ``(k + 1/2) / ppc``, aligned to the global grid so that touching bodies
tile without gaps or overlaps; each carries the volume ``(dx / ppc)^dim``.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..errors import SceneError
from ..scene import Scene, body_bounds
from .mesh import inside_mesh


def lattice(lower, upper, domain_lo, spacing: float) -> np.ndarray:
    """Lattice points ``domain_lo + (k + 1/2) spacing`` in the half-open box [lower, upper).

    Half-open so that two bodies sharing a face never both take (or both miss) a point that
    lies exactly on it; the integer range decides membership, not a float comparison."""
    axes = []
    for lo, hi, origin in zip(lower, upper, domain_lo):
        k0 = int(np.ceil((lo - origin) / spacing - 0.5))
        k1 = int(np.ceil((hi - origin) / spacing - 0.5))
        axes.append(origin + (np.arange(k0, max(k0, k1)) + 0.5) * spacing)
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


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


def sample_body(body, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, dim) and volumes (n,) of the particles filling ``body``."""
    dim = scene.dim
    spacing = scene.dx / scene.particles_per_cell
    lower, upper = body_bounds(body.shape, body.params, dim)
    x = lattice(lower, upper, scene.domain_lo, spacing)
    x = x[inside(body, x, dim)]
    if body.jitter > 0 and len(x):
        rng = np.random.default_rng(body.seed)
        x = x + rng.uniform(-0.5, 0.5, size=x.shape) * body.jitter * spacing
    # float64, not Python float: an absurd spacing gives inf (reported) instead of OverflowError
    return np.ascontiguousarray(x), np.full(len(x), np.float64(spacing) ** dim)


def initial_velocity(body, x: np.ndarray, dim: int) -> np.ndarray:
    """Body velocity plus rigid spin about the body's centroid, plus an optional field."""
    v = np.tile(np.asarray(body.velocity, dtype=np.float64), (len(x), 1))
    if len(x) == 0:
        return v
    r = x - x.mean(axis=0)
    w = body.angular_velocity
    if dim == 2:
        v += float(w) * np.stack([-r[:, 1], r[:, 0]], axis=1)
    else:
        v += np.cross(np.asarray(w, dtype=np.float64), r)
    f = body.velocity_field
    if f is not None and f["type"] == "axial_mode":
        # First axial mode of a bar fixed at 0 and free at L: v = A sin(pi x / 2L).
        v[:, f["axis"]] += f["amplitude"] * np.sin(np.pi * x[:, f["axis"]] / (2 * f["length"]))
    return v


def sampling_memory_limit() -> int:
    """Bytes the sampling of a scene may take: the memory this machine has available now
    (``MemAvailable``), else its physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def lattice_points(scene: Scene) -> list[float]:
    """Points of each body's bounding-box lattice (what `lattice` allocates before the shape
    test), as floats: an estimate that cannot overflow, computed before anything is allocated."""
    spacing = scene.dx / scene.particles_per_cell
    counts = []
    for body in scene.bodies:
        lower, upper = body_bounds(body.shape, body.params, scene.dim)
        n = 1.0
        for lo, hi in zip(lower, upper):
            n *= max((hi - lo) / spacing, 1.0) if spacing > 0 else math.inf
        counts.append(n)
    return counts


def check_sample_size(scene: Scene) -> None:
    """Raise `SceneError` when sampling ``scene`` would need more memory than this machine has,
    before anything is allocated (a typo such as ``particles_per_cell = 2000`` must get a
    verdict, not a MemoryError or an exhausted machine)."""
    # Bytes per lattice point while sampling: the meshgrid axes and their stack (2 dim
    # float64), the kept positions and velocities (2 dim), mass, volume, id, mask and group.
    per_point = 8 * (4 * scene.dim + 5)
    counts = lattice_points(scene)
    total = math.fsum(counts) if all(math.isfinite(n) for n in counts) else math.inf
    limit = sampling_memory_limit()
    if total * per_point > limit:
        raise SceneError(
            f"{scene.path}: simulation.particles_per_cell: sampling the bodies would take about "
            f"{total:.3g} particles ({total * per_point / 2**30:.3g} GiB), more than the "
            f"{limit / 2**30:.3g} GiB of memory available here; use a larger simulation.dx "
            f"or fewer particles_per_cell (now dx = {scene.dx:g}, particles_per_cell = "
            f"{scene.particles_per_cell})")


def sample_scene(scene: Scene) -> dict[str, np.ndarray]:
    """Every body's particles: x, v, mass, vol0, group (material index), id (0..N-1 in body
    order; deterministic, so every rank computes the same ids)."""
    check_sample_size(scene)
    parts = []
    for index, body in enumerate(scene.bodies):
        x, vol = sample_body(body, scene)
        if len(x) == 0:
            raise SceneError(f"{scene.path}: bodies[{index}]: holds no particles (smaller than "
                             f"the particle spacing dx / particles_per_cell = "
                             f"{scene.dx / scene.particles_per_cell:g}?)")
        group = scene.material_index(body.material)
        density = scene.materials[group].density
        with np.errstate(all="ignore"):  # non-finite values are reported just below
            v = initial_velocity(body, x, scene.dim)
            mass = density * vol
        if not (np.isfinite(v).all() and np.isfinite(mass).all() and (mass > 0).all()):
            raise SceneError(f"{scene.path}: bodies[{index}]: initial velocity or mass is not "
                             f"finite (velocity, angular_velocity, velocity_field or density "
                             f"out of range)")
        parts.append({"x": x, "v": v, "mass": mass,
                      "vol0": vol, "group": np.full(len(x), group, dtype=np.int32)})
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
    out["id"] = np.arange(len(out.get("x", ())), dtype=np.int64)
    return out

"""Shared set-up of the MPI tests: the same global particle cloud on every rank, a strided
share of it per rank, and serial (numpy, one process) references computed from the whole cloud.
"""

from __future__ import annotations

import itertools

import numpy as np

from hpcmpm.parallel import Domain
from hpcmpm.state import SCALAR, TENSOR, FieldSpec, GridBlock, ParticleSet

EXTRA_FIELDS = {"F": FieldSpec(TENSOR, "f8", "identity"),
                "Fp": FieldSpec(TENSOR, "f8", "identity"), "tag": FieldSpec(SCALAR, "i4", 0),
                "tau": FieldSpec(TENSOR)}


def cloud(dim: int, n: int, seed: int, lo=0.0, hi=1.0) -> dict[str, np.ndarray]:
    """n particles with every core field and two extra fields, each a function of its id."""
    rng = np.random.default_rng(seed)
    ids = np.arange(n, dtype=np.int64) * 7 + 3  # not 0..n-1, so an id is not a position
    x = rng.uniform(lo, hi, size=(n, dim))
    return with_fields_of_id(ids, x)


def with_fields_of_id(ids: np.ndarray, x: np.ndarray) -> dict[str, np.ndarray]:
    n, dim = x.shape
    f = ids.astype(np.float64)
    eye = np.eye(dim)
    return {
        "id": ids, "x": x, "group": (ids % 3).astype(np.int32),
        "v": np.stack([np.sin(f + a) for a in range(dim)], axis=1),
        "mass": 1.0 + 0.001 * f, "vol0": 0.5 + 1e-4 * f,
        "F": eye + 1e-3 * f[:, None, None] * np.arange(dim * dim).reshape(dim, dim),
        "tau": np.cos(f)[:, None, None] * np.ones((dim, dim)),
        "Fp": eye - 1e-4 * f[:, None, None],
        "tag": (ids % 1000).astype(np.int32),
    }


def particle_set(dim: int, values: dict[str, np.ndarray], index=None) -> ParticleSet:
    p = ParticleSet(dim, dict(EXTRA_FIELDS))
    if index is None:
        index = np.arange(len(values["id"]))
    p.append({k: v[index] for k, v in values.items()})
    return p


def strided_share(values: dict[str, np.ndarray], domain: Domain) -> np.ndarray:
    return np.flatnonzero(np.arange(len(values["id"])) % domain.size == domain.rank)


def gather_by_id(domain: Domain, p: ParticleSet) -> dict[str, np.ndarray]:
    """Every rank's particles, concatenated and sorted by id (on every rank)."""
    parts = domain.allgather(p.snapshot())
    merged = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    order = np.argsort(merged["id"], kind="stable")
    return {k: v[order] for k, v in merged.items()}


def support_offsets(dim: int) -> np.ndarray:
    """Node offsets c-1 .. c+2 per axis around a particle's cell: (4**dim, dim)."""
    return np.array(list(itertools.product(range(-1, 3), repeat=dim)), dtype=np.int64)


def deposit(x, ids, mass, v, domain_lo, dx, origin, shape):
    """Synthetic P2G: each particle adds a weight that depends on its id and on the node offset
    to the 4**dim nodes c-1..c+2 (scalar ``mass``) and ``weight * v`` (vector ``momentum``).
    Returns (mass, momentum, touched) arrays over the box ``origin + shape``."""
    dim = x.shape[1]
    offsets = support_offsets(dim)
    cells = np.floor((x - domain_lo) * (1.0 / dx)).astype(np.int64)
    nodes = cells[:, None, :] + offsets[None] - np.asarray(origin)
    flat = np.ravel_multi_index(nodes.reshape(-1, dim).T, shape)
    w = (mass[:, None] * (1.0 + 0.01 * (ids % 13))[:, None]
         * (1.0 + 0.1 * np.arange(len(offsets)))[None]).ravel()
    size = int(np.prod(shape))
    m = np.bincount(flat, weights=w, minlength=size).reshape(shape)
    mom = np.stack([np.bincount(flat, weights=w * np.repeat(v[:, a], len(offsets)),
                                minlength=size).reshape(shape) for a in range(dim)], axis=-1)
    touched = np.bincount(flat, minlength=size).reshape(shape) > 0
    return m, mom, touched


def reference_grid(values, domain: Domain):
    """The one-process grid of all particles over nodes -10 .. n_cells + 10 (room for a block's
    allocation margin around the support of particles just beyond the walls)."""
    origin = np.full(domain.dim, -10, dtype=np.int64)
    shape = tuple(int(n) + 21 for n in domain.n_cells)
    m, mom, _ = deposit(values["x"], values["id"], values["mass"], values["v"],
                        domain.domain_lo, domain.dx, origin, shape)
    return origin, m, mom


def block_grid(domain: Domain, p: ParticleSet) -> GridBlock:
    grid = GridBlock(domain.dim, domain.dx, domain.domain_lo)
    grid.declare("mass", SCALAR)
    grid.declare("momentum", "vector")
    grid.fit(*domain.grid_box(p, 2))
    return grid

"""Particle and grid storage.

`ParticleSet` is a structure of arrays with spare capacity: fields are named, allocated on
demand from what the scene's materials and features declare, and particles are added, removed
and reordered without reallocating every array every step. `GridBlock` is the rank-local dense
block of grid nodes (owned nodes plus ghost layers) that covers this rank's particles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kernels.particles import complete_permutation, permute_rows

# Shape kinds of a per-particle field: the trailing shape follows from the dimension.
SCALAR, VECTOR, TENSOR = "scalar", "vector", "tensor"


@dataclass(frozen=True)
class FieldSpec:
    """How a per-particle field is stored: `kind` in {scalar, vector, tensor}, dtype, and the
    value a new particle gets when nobody provides one (`"identity"` for tensors such as F)."""

    kind: str = SCALAR
    dtype: str = "f8"
    fill: float | str = 0.0

    def trailing_shape(self, dim: int) -> tuple[int, ...]:
        return {SCALAR: (), VECTOR: (dim,), TENSOR: (dim, dim)}[self.kind]


# Fields every MPM particle has. `group` is the index of the particle's material in the scene.
# The Kirchhoff stress is not a field: it lives in a chunk-sized buffer between the material
# kernel and P2G (`Simulation.scatter_stress`), which saves 72 B per 3D particle.
CORE_FIELDS: dict[str, FieldSpec] = {
    "id": FieldSpec(SCALAR, "i8", -1),
    "group": FieldSpec(SCALAR, "i4", 0),
    "x": FieldSpec(VECTOR),
    "v": FieldSpec(VECTOR),
    "mass": FieldSpec(SCALAR),
    "vol0": FieldSpec(SCALAR),
}
# The deformation state: the gradient F, or its determinant J alone when every material of
# the scene is volumetric (`hpcmpm.kernels.deformation`). A simulation declares one of them.
DEFORMATION_FIELDS: dict[str, FieldSpec] = {
    "F": FieldSpec(TENSOR, "f8", "identity"),
    "J": FieldSpec(SCALAR, "f8", 1.0),
}


class ParticleSet:
    """Structure of arrays of particles.

    ``p["x"]`` is a view of the first ``p.n`` rows of the backing array, so kernels see
    contiguous float64 arrays of exactly the live particles. Capacity grows geometrically.
    """

    def __init__(self, dim: int, specs: dict[str, FieldSpec] | None = None, capacity: int = 0):
        self.dim = dim
        self.n = 0
        self.capacity = 0
        self.specs: dict[str, FieldSpec] = {}
        self._data: dict[str, np.ndarray] = {}
        for name, spec in {**CORE_FIELDS, **(specs or {})}.items():
            self.add_field(name, spec)
        self._reserve(max(capacity, 16))

    # -- fields -----------------------------------------------------------------------------
    def add_field(self, name: str, spec: FieldSpec) -> None:
        """Declare a field; existing particles get the spec's fill value. Idempotent."""
        if name in self.specs:
            if self.specs[name] != spec:
                raise ValueError(f"field {name!r} already declared as {self.specs[name]}")
            return
        self.specs[name] = spec
        arr = np.empty((self.capacity,) + spec.trailing_shape(self.dim), dtype=spec.dtype)
        self._fill(arr, spec)
        self._data[name] = arr

    def __contains__(self, name: str) -> bool:
        return name in self.specs

    def __getitem__(self, name: str) -> np.ndarray:
        return self._data[name][: self.n]

    def field_names(self) -> list[str]:
        return list(self.specs)

    def nbytes_per_particle(self) -> int:
        return sum(a.itemsize * int(np.prod(a.shape[1:])) for a in self._data.values())

    def _fill(self, arr: np.ndarray, spec: FieldSpec) -> None:
        if spec.fill == "identity":
            arr[...] = 0.0
            for a in range(self.dim):
                arr[..., a, a] = 1.0
        else:
            arr[...] = spec.fill

    # -- size -------------------------------------------------------------------------------
    def _reserve(self, needed: int) -> None:
        if needed <= self.capacity:
            return
        new_cap = max(needed, int(self.capacity * 1.5) + 16)
        for name, spec in self.specs.items():
            old = self._data.get(name)
            arr = np.empty((new_cap,) + spec.trailing_shape(self.dim), dtype=spec.dtype)
            self._fill(arr[self.n :], spec)
            if old is not None and self.n:
                arr[: self.n] = old[: self.n]
            self._data[name] = arr
        self.capacity = new_cap

    def reserve(self, n: int) -> None:
        """Make room for ``n`` particles in all, so appends up to that many do not grow the
        arrays by half on the way (start-up knows its share in advance)."""
        self._reserve(n)

    def append(self, values: dict[str, np.ndarray]) -> None:
        """Add particles. ``values`` maps field names to arrays with equal first dimension;
        fields not given take their fill value. Unknown names are an error."""
        unknown = set(values) - set(self.specs)
        if unknown:
            raise KeyError(f"unknown particle fields {sorted(unknown)}")
        if not values:
            return
        m = len(next(iter(values.values())))
        start = self.n
        self._reserve(self.n + m)
        for name, spec in self.specs.items():
            dst = self._data[name][start : start + m]
            if name in values:
                dst[...] = values[name]
            else:
                self._fill(dst, spec)
        self.n += m

    def append_rows(self, values: dict[str, np.ndarray], index: np.ndarray,
                    chunk: int = 16384) -> None:
        """Append rows ``index`` of ``values`` (full-size arrays, e.g. a sampled scene), a
        chunk at a time after one exact reservation: the copies in flight stay at ``chunk``
        rows instead of a second copy of the whole input."""
        index = np.asarray(index, dtype=np.int64)
        self._reserve(self.n + len(index))
        for start in range(0, len(index), chunk):
            rows = index[start:start + chunk]
            self.append({k: np.asarray(v)[rows] for k, v in values.items()})

    def remove(self, index: np.ndarray) -> None:
        """Remove the particles at ``index`` (integer indices, unique) in O(len(index)): the
        holes are filled with particles from the tail, so the order is not kept (the next
        sort restores it). Migration uses this: its cost follows the particles that leave."""
        index = np.unique(np.asarray(index, dtype=np.int64))
        k = len(index)
        if k == 0:
            return
        n_new = self.n - k
        holes = index[index < n_new]
        tail = np.ones(k, dtype=bool)
        tail[index[index >= n_new] - n_new] = False
        movers = n_new + np.flatnonzero(tail)
        for name, spec in self.specs.items():
            data = self._data[name]
            data[holes] = data[movers]
            self._fill(data[n_new : self.n], spec)
        self.n = n_new

    def keep(self, index: np.ndarray) -> None:
        """Keep only the particles at ``index`` (a boolean mask or integer index), in that order."""
        index = np.asarray(index)
        if index.dtype == bool:
            index = np.flatnonzero(index)
        self.permute(index)

    def permute(self, order: np.ndarray) -> None:
        """Reorder (and possibly shrink to) ``order``, distinct integer indices into the live
        particles.

        In place, field by field, following the cycles of the permutation: peak memory grows
        by one index and one flag per particle, not by a copy of every field (which had
        doubled the peak resident size of a 3D run)."""
        order = np.asarray(order, dtype=np.int64)
        m, n = len(order), self.n
        if n == 0:
            return
        perm = np.empty(n, dtype=np.int64)
        done = np.empty(n, dtype=np.bool_)
        complete_permutation(order, n, perm, done)
        for name, spec in self.specs.items():
            rows = self._data[name][:n].reshape(n, -1)
            permute_rows(rows, perm, done, np.empty(rows.shape[1], dtype=rows.dtype))
            self._fill(self._data[name][m:n], spec)
        self.n = m

    def take(self, index: np.ndarray, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Copies of the given particles' fields (for migration, halos and output)."""
        names = self.field_names() if names is None else names
        return {name: self[name][index] for name in names}

    def snapshot(self) -> dict[str, np.ndarray]:
        """Copies of every live field."""
        return {name: self[name].copy() for name in self.specs}


class GridBlock:
    """A dense block of grid nodes on one rank.

    Node ``i`` (a global integer index per axis) sits at ``domain_lo + i * dx``. The block holds
    nodes ``origin <= i < origin + shape``; ``lo``/``hi`` are the sub-box in use this step (the
    allocation may be larger so it is reused while the particles move). Fields are named like
    particle fields: ``mass`` has shape ``shape``, vector fields ``shape + (dim,)``.
    """

    def __init__(self, dim: int, dx: float, domain_lo: np.ndarray, margin: int = 4):
        self.dim = dim
        self.dx = float(dx)
        self.domain_lo = np.asarray(domain_lo, dtype=np.float64)
        self.margin = margin
        self.origin = np.zeros(dim, dtype=np.int64)
        self.shape: tuple[int, ...] = (0,) * dim
        self.lo = np.zeros(dim, dtype=np.int64)
        self.hi = np.zeros(dim, dtype=np.int64)
        self.kinds: dict[str, str] = {}
        self.fields: dict[str, np.ndarray] = {}
        self.reallocations = 0

    def declare(self, name: str, kind: str = SCALAR) -> None:
        """Declare a grid field (scalar or vector); allocated at the next `fit`."""
        if name not in self.kinds:
            self.kinds[name] = kind
            self.fields[name] = self._alloc(kind)

    def _alloc(self, kind: str) -> np.ndarray:
        trailing = (self.dim,) if kind == VECTOR else ()
        return np.zeros(self.shape + trailing, dtype=np.float64)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    def fit(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Make the block hold nodes ``lo <= i < hi`` and zero every field.

        Reallocates (with ``margin`` spare nodes per side) only when the box does not fit, or
        when the allocation is more than 4x the need, so a block that once covered a
        spread-out body does not keep zeroing empty space forever. (Plain ints: this runs
        every step, and NumPy calls on 3-element arrays cost more than the zeroing of a
        small 2D block.)"""
        lo = [int(a) for a in lo]
        hi = [max(int(b), a) for a, b in zip(lo, hi)]
        origin = [int(a) for a in self.origin]
        end = [a + s for a, s in zip(origin, self.shape)]
        need = math.prod(b - a + 2 * self.margin for a, b in zip(lo, hi))
        if (any(a < o for a, o in zip(lo, origin)) or any(b > e for b, e in zip(hi, end))
                or math.prod(self.shape) > 4 * max(need, 1)):
            self.origin = np.array(lo, dtype=np.int64) - self.margin
            self.shape = tuple(b - a + 2 * self.margin for a, b in zip(lo, hi))
            for name, kind in self.kinds.items():
                self.fields[name] = self._alloc(kind)
            self.reallocations += 1
        else:
            for arr in self.fields.values():
                arr.fill(0.0)
        self.lo = np.array(lo, dtype=np.int64)
        self.hi = np.array(hi, dtype=np.int64)

    def node_positions(self) -> list[np.ndarray]:
        """1D coordinate arrays per axis for the allocated nodes."""
        return [self.domain_lo[a] + (self.origin[a] + np.arange(self.shape[a])) * self.dx
                for a in range(self.dim)]

    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.fields.values())

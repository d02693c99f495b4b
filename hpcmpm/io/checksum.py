"""A checksum of a dataset that ranks holding different row ranges can compute together.

CRC32 and SHA-256 are sequential: the rank holding rows 1000..1999 cannot contribute without
the state after row 999, and a restart on another rank count slices the rows differently.
This checksum is instead a sum over the dataset's elements, in C order, of
``splitmix64(bits(element) + golden * (global element index + 1))`` modulo 2**64: each rank sums
its own rows, and the partial sums add up to the same value for every partition. A flipped bit
changes its element's term (splitmix64 is a bijection with full avalanche), hence the sum,
except with probability about 2**-64; swapping two rows changes it too, because the index
enters each term. It detects corruption; it is not a defence against deliberate tampering.
"""

from __future__ import annotations

import numpy as np

MASK = (1 << 64) - 1
ALGORITHM = "splitmix64-sum"
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_CHUNK = 1 << 20  # elements per pass: bounds the temporary arrays to a few MiB


def _element_words(array: np.ndarray) -> np.ndarray:
    """The array's bytes as unsigned integers of the widest size dividing the itemsize."""
    flat = np.ascontiguousarray(array).reshape(-1)
    size = flat.dtype.itemsize
    width = next(w for w in (8, 4, 2, 1) if size % w == 0)
    return flat.view(np.uint8).view(f"<u{width}") if flat.size else np.zeros(0, f"<u{width}")


def words_per_row(array: np.ndarray) -> int:
    """How many checksum words one row (first axis) of ``array`` has."""
    size = array.dtype.itemsize
    width = next(w for w in (8, 4, 2, 1) if size % w == 0)
    return int(np.prod(array.shape[1:], dtype=np.int64)) * (size // width)


def partial_checksum(array: np.ndarray, first_row: int = 0) -> int:
    """This slice's contribution, ``array`` being rows ``first_row..`` of the whole dataset."""
    words = _element_words(array)
    base = int(first_row) * words_per_row(array)
    total = 0
    with np.errstate(over="ignore"):
        for start in range(0, len(words), _CHUNK):
            w = words[start:start + _CHUNK].astype(np.uint64)
            index = np.arange(base + start + 1, base + start + 1 + len(w), dtype=np.uint64)
            z = w + index * _GOLDEN
            z = (z ^ (z >> np.uint64(30))) * _M1
            z = (z ^ (z >> np.uint64(27))) * _M2
            z = z ^ (z >> np.uint64(31))
            # Sum in two 32-bit halves so the reduction cannot lose carries.
            lo = int(np.sum(z & np.uint64(0xFFFFFFFF), dtype=np.uint64))
            hi = int(np.sum(z >> np.uint64(32), dtype=np.uint64))
            total = (total + lo + (hi << 32)) & MASK
    return total


def combine(partials) -> int:
    return sum(int(p) for p in partials) & MASK


def checksum(array: np.ndarray) -> int:
    return partial_checksum(array, 0)


def format_checksum(value: int) -> str:
    return f"{value:016x}"

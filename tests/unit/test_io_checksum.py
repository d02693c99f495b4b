"""The checkpoint checksum is a file format: its value for given data must never change, or
every checkpoint written before the change reads as corrupt. Checked against a pure-Python
implementation of the documented formula (hpcmpm/io/checksum.py) and against the published
first outputs of splitmix64 (Vigna's reference generator seeded with 0), so a change of the
word width, the element index, the mixer or the reduction is caught even where it still
detects corruption."""

from __future__ import annotations

import numpy as np
import pytest

from hpcmpm.io import checksum as cks

GOLDEN = 0x9E3779B97F4A7C15
MASK = (1 << 64) - 1
# splitmix64 seeded with 0: its first three outputs (prng.di.unimi.it/splitmix64.c).
SPLITMIX64_SEED0 = (0xE220A8397B1DCDAF, 0x6E789E6AA1B965F4, 0x06C45D188009454F)


def splitmix64(z: int) -> int:
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def reference(array: np.ndarray, first_row: int = 0) -> int:
    """sum over words i (C order) of splitmix64(word_i + golden * (global index + 1)) mod
    2**64, words being the widest little-endian unsigned size dividing the itemsize."""
    size = array.dtype.itemsize
    width = next(w for w in (8, 4, 2, 1) if size % w == 0)
    raw = np.ascontiguousarray(array).tobytes()
    per_row = (int(np.prod(array.shape[1:], dtype=np.int64)) * size) // width
    base = first_row * per_row
    total = 0
    for i in range(len(raw) // width):
        word = int.from_bytes(raw[i * width:(i + 1) * width], "little")
        total += splitmix64((word + GOLDEN * (base + i + 1)) & MASK)
    return total & MASK


def test_zero_words_give_the_published_splitmix64_outputs():
    # Word 0 at index k contributes splitmix64(golden * (k + 1)), the (k+1)-th output of
    # splitmix64 seeded with 0.
    for k in range(3):
        assert cks.checksum(np.zeros(k + 1, np.uint64)) == sum(SPLITMIX64_SEED0[:k + 1]) & MASK
    assert cks.format_checksum(cks.checksum(np.zeros(1, np.uint64))) == "e220a8397b1dcdaf"


@pytest.mark.parametrize("dtype,trailing", [("f8", (3,)), ("f4", (3, 3)), ("i4", ()),
                                            ("?", ()), ("i8", ()), ("u2", (2,)),
                                            ("c16", ())])
def test_checksum_matches_the_documented_formula(dtype, trailing):
    """Every dtype a checkpoint stores (bool and 4-byte fields have words narrower than 8
    bytes; a 16-byte complex element is two words), whole and as a slice starting at row 5
    (a rank's share: its words are numbered from row 5's first word)."""
    rng = np.random.default_rng(3)
    a = (rng.standard_normal((17,) + trailing) * 1000).astype(dtype)
    assert cks.checksum(a) == reference(a)
    assert cks.partial_checksum(a[5:], 5) == reference(a[5:], 5)
    assert cks.combine([cks.partial_checksum(a[:5], 0), cks.partial_checksum(a[5:], 5)]) \
        == reference(a)

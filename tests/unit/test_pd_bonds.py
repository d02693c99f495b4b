"""Bond CSR side structure: segments move with their particles, slots resolve through ids."""

import numpy as np
import pytest

from hpcmpm.pd.bonds import Bonds, image_label


def small_bonds():
    # Three particles with 2, 0, 3 half-bonds; partner ids ascending per segment.
    offsets = np.array([0, 2, 2, 5])
    partner = np.array([11, 12, 10, 11, 13])
    weight = np.array([0.5, 1.0, 0.25, 0.75, 1.0])
    status = np.array([1, 0, 1, 1, 1], dtype=np.int8)
    b = Bonds(offsets, partner, weight, status)
    b.add_state("plastic_stretch")[:] = [1.0, 2.0, 3.0, 4.0, 5.0]
    return b


def segment(b, i):
    s = slice(b.offsets[i], b.offsets[i + 1])
    return b.partner[s].tolist(), b.weight[s].tolist(), b.status[s].tolist(), \
        b.state["plastic_stretch"][s].tolist()


def test_resident_bytes_per_half_bond():
    b = small_bonds()
    # partner i8 + weight f8 + slot i4 + status i1 + image i1 = 22 B, + 8 B per per-bond
    # state array.
    assert b.resident_bytes_per_bond() == 22 + 8
    assert Bonds.empty(3).resident_bytes_per_bond() == 22


def test_permute_keeps_each_particles_segment():
    b = small_bonds()
    before = [segment(b, i) for i in range(3)]
    b.permute([2, 0, 1])
    assert [segment(b, i) for i in range(3)] == [before[2], before[0], before[1]]
    b.keep(np.array([True, False, True]))
    assert [segment(b, i) for i in range(2)] == [before[2], before[1]]


def test_extract_append_round_trip_as_migration():
    b = small_bonds()
    before = [segment(b, i) for i in range(3)]
    counts, arrays = b.extract([2, 0])
    assert counts.tolist() == [3, 2]
    b.keep([1])                       # the two leave ...
    b.append(counts, arrays)          # ... and arrive elsewhere (here: back)
    assert [segment(b, i) for i in range(3)] == [before[1], before[2], before[0]]
    assert np.all(b.slot == -1)       # slots mean nothing after a move


def test_append_new_segments_starts_state_at_zero():
    b = small_bonds()
    b.append([1], {"partner": np.array([7]), "weight": np.array([1.0]),
                   "status": np.array([1], np.int8)})
    assert segment(b, 3) == ([7], [1.0], [1], [0.0])


def test_resolve_slots_finds_rows_and_nearest_periodic_image():
    b = small_bonds()
    # Points: owned rows 0..2 (ids 10, 11, 12), halo: id 13 and two images of id 10.
    ids = np.array([10, 11, 12, 13, 10, 10])
    x0 = np.array([[0.0], [1.0], [2.0], [3.0], [10.0], [-10.0]])
    x0 = np.hstack([x0, np.zeros_like(x0)])
    missing = b.resolve_slots(ids, x0)
    assert missing == 0
    # particle 2 (x0 = 2) reaches id 10 at row 0 (x0 = 0), not the images at +-10.
    assert b.slot.tolist() == [1, 2, 0, 1, 3]
    # Without id 12 in the halo: the bond to it is broken, so it may be absent.
    assert b.resolve_slots(np.array([10, 11, 13]), x0[[0, 1, 3]]) == 0
    b.status[:] = 1
    assert b.resolve_slots(np.array([10, 11, 13]), x0[[0, 1, 3]]) == 1


@pytest.mark.parametrize("near_row", [4, 5])
def test_resolve_slots_takes_the_nearest_image_whatever_its_row(near_row):
    """Among the copies of one id (the owned row and periodic images) the partner is the one
    nearest to the bond's owner in x0, wherever it sits in the rows: here an image (x0 =
    3.5, 1.5 from particle 2 at x0 = 2) is nearer than the owned row of id 10 (x0 = 0, at
    2) and the other image (x0 = -10)."""
    b = small_bonds()
    ids = np.array([10, 11, 12, 13, 10, 10])
    x = np.array([0.0, 1.0, 2.0, 3.0, -10.0, -10.0])
    x[near_row] = 3.5
    x0 = np.stack([x, np.zeros_like(x)], axis=1)
    assert b.resolve_slots(ids, x0) == 0
    assert b.slot.tolist() == [1, 2, near_row, 1, 3]


def test_image_labels_tell_the_images_of_one_partner_apart():
    """Along a periodic axis (period 4) the offsets d and d - 4 of one partner get different
    labels, including the tie d = +-2 (half the period), whatever the round-off; a
    non-periodic axis counts 0."""
    period = np.array([4.0, 0.0])
    label = lambda *X: image_label(np.array(X, float), period)  # noqa: E731
    for d in (0.5, 1.5, 2.0, 2.0 - 1e-12, 2.0 + 1e-12, 3.5):
        assert label(d, 0.3) != label(d - 4.0, 0.3), d
    assert label(2.0 * (1 + 1e-15), 7.0) == label(2.0 * (1 - 1e-15), -7.0)
    assert label(-2.0 * (1 + 1e-15), 0.0) == label(-2.0 * (1 - 1e-15), 0.0)
    assert label(0.0, 5.0) == label(1.9, -5.0) == label(-1.9, 1.0) == 0  # the minimum image
    assert len({label(d, 0.0) for d in (-3.0, 1.0, 3.0)}) == 3
    label3 = lambda *X: image_label(np.array(X, float), np.array([4.0, 4.0, 4.0]))  # noqa
    codes = {label3(a, b, c) for a in (-3.0, 1.0, 3.0) for b in (-3.0, 1.0, 3.0)
             for c in (-3.0, 1.0, 3.0)}
    assert codes == set(range(27))
    # Two periods away (a narrow axis's halo holds such copies): no bond's image.
    assert label(7.0, 0.0) == label(-7.0, 0.0) == -1


@pytest.mark.parametrize("rows", [(4, 5), (5, 4)])
def test_resolve_slots_gives_each_image_of_a_partner_its_own_copy(rows):
    """A particle bonded twice to id 10 across a periodic axis (period 4: offsets +2 and -2,
    labels from `image_label`) takes the halo copy with each half-bond's label, wherever the
    copies sit in the rows; with one copy gone its half-bond, broken, is unresolved and the
    other still finds its own copy; a partner bonded once takes its nearest copy."""
    period = np.array([4.0, 0.0])
    x0 = np.array([[1.0, 0.0], [0.0, 0.0], [2.0, 0.0], [3.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    x0[rows[0], 0], x0[rows[1], 0] = 3.0, -1.0       # the two images of id 10 (x0 = 3, -1)
    ids = np.array([1, 11, 12, 13, 10, 10])
    up, down = (image_label(np.array([s, 0.0]), period) for s in (2.0, -2.0))
    b = Bonds([0, 3], [10, 10, 11], [1.0, 1.0, 1.0], image=sorted([up, down]) + [0])
    assert b.resolve_slots(ids, x0, period) == 0
    want = {up: 3.0, down: -1.0}
    assert [x0[b.slot[k], 0] for k in range(2)] == [want[g] for g in b.image[:2]]
    assert b.slot[2] == 1
    gone = rows[0]                                    # the copy at x0 = 3 leaves the halo
    keep = np.flatnonzero(np.arange(6) != gone)
    b.status[b.image == up] = 0
    assert b.resolve_slots(ids[keep], x0[keep], period) == 0
    assert b.slot[b.image == up][0] == -1
    assert x0[keep][b.slot[b.image == down][0], 0] == -1.0
    b.status[:] = 1
    assert b.resolve_slots(ids[keep], x0[keep], period) == 1


def test_resolve_slots_skips_a_copy_two_periods_away():
    """On an axis narrower than the halo's reach (period 4) the halo holds copies of a
    partner one and two periods from its image: a half-bond reaching X = +2.5 (label of
    n = 1) takes that copy, not the one at +6.5 listed before it."""
    period = np.array([4.0, 0.0])
    x0 = np.array([[0.0, 0.0], [6.5, 0.0], [-1.5, 0.0], [2.5, 0.0]])
    ids = np.array([1, 10, 10, 10])
    b = Bonds([0, 1], [10], [1.0], image=[image_label(np.array([2.5, 0.0]), period)])
    assert b.resolve_slots(ids, x0, period) == 0
    assert b.slot[0] == 3


def test_intact_counts():
    assert small_bonds().intact_counts().tolist() == [1, 0, 3]


def test_merge_keeps_segments_ordered_by_partner_id():
    b = small_bonds()
    b.merge([0, 2, 1], [5, 12, 20], [0.1, 0.2, 0.3])
    assert segment(b, 0) == ([5, 11, 12], [0.1, 0.5, 1.0], [1, 1, 0], [0.0, 1.0, 2.0])
    assert segment(b, 1) == ([20], [0.3], [1], [0.0])
    assert segment(b, 2) == ([10, 11, 12, 13], [0.25, 0.75, 0.2, 1.0], [1, 1, 1, 1],
                             [3.0, 4.0, 0.0, 5.0])
    with pytest.raises(ValueError, match="duplicate"):
        b.merge([0], [11], [1.0])
    with pytest.raises(ValueError, match="duplicate"):          # twice among the new ones
        b.merge([1, 1], [30, 30], [1.0, 1.0])


def test_merge_equals_sorting_everything():
    """`merge` merges the new half-bonds into the ordered segments (a linear pass); the
    result must be what sorting all half-bonds by (row, partner) gives, every array and
    the offsets, for random segments (empty ones included) and random new bonds in random
    order."""
    rng = np.random.default_rng(3)
    n = 40
    counts = rng.integers(0, 6, n)
    counts[[0, 7, 39]] = 0
    partner = np.concatenate([np.sort(rng.choice(1000, c, replace=False)) for c in counts])
    b = Bonds(np.concatenate([[0], np.cumsum(counts)]), partner, rng.random(len(partner)),
              rng.integers(0, 2, len(partner)).astype(np.int8))
    b.add_state("s")
    b.state["s"][:] = rng.random(b.n_bonds)
    b.slot[:] = rng.integers(0, 50, b.n_bonds)
    pairs = {(int(r), int(q)) for r, q in zip(np.repeat(np.arange(n), counts), partner)}
    new = []
    while len(new) < 60:
        r, q = int(rng.integers(0, n)), int(rng.integers(0, 1000))
        if (r, q) not in pairs:
            pairs.add((r, q))
            new.append((r, q))
    rows = np.array([r for r, _ in new])
    new_partner = np.array([q for _, q in new])
    weight = rng.random(len(new))
    owner = np.concatenate([np.repeat(np.arange(n), counts), rows])
    allp = np.concatenate([partner, new_partner])
    ref = np.lexsort((allp, owner))
    want = {"partner": allp[ref], "weight": np.concatenate([b.weight, weight])[ref],
            "status": np.concatenate([b.status, np.ones(len(new), np.int8)])[ref],
            "slot": np.concatenate([b.slot, np.full(len(new), -1, np.int32)])[ref],
            "s": np.concatenate([b.state["s"], np.zeros(len(new))])[ref]}
    b.merge(rows, new_partner, weight)
    assert np.array_equal(b.offsets, np.concatenate([[0], np.cumsum(np.bincount(owner,
                                                                               minlength=n))]))
    for name in ("partner", "weight", "status", "slot"):
        assert np.array_equal(getattr(b, name), want[name]), name
    assert np.array_equal(b.state["s"], want["s"])

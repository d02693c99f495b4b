"""The PD particle halo (`hpcmpm.parallel.pd_halo.PDHalo`) against its contract, directly: a
plan built at positions x still holds every partner within ``reach`` of each owned particle
after every particle moved by less than skin/2 (the reason the plan ships ``reach + skin``),
`stale` says so on every rank as soon as one particle moved more than skin/2 (distance, not a
coordinate), and a periodic image carries both its position fields shifted by the period.

The scene tests reach the halo only through bond forces, where a partner shipped one build
late, or a reference position off by a period, changes few bonds; here each halo row is
checked by id and position. x axis periodic, so 1 rank has images of its own particles and
2 ranks (a cut along x) exchange images across the periodic face."""

import numpy as np
import pytest

from hpcmpm.parallel import Domain
from hpcmpm.parallel.pd_halo import PDHalo, align_rows
from mpi_helpers import cloud, particle_set, strided_share

REACH, SKIN = 0.1, 0.04


def displacement(ids: np.ndarray, length: float) -> np.ndarray:
    """A move of ``length`` in a direction that depends on the id."""
    angle = (ids % 97) * (2 * np.pi / 97)
    return length * np.stack([np.cos(angle), np.sin(angle)], axis=1)


def reference_x(ids, x):
    """A reference configuration that differs from x per particle (so an unshifted x0 shows)."""
    return x - 0.01 * np.stack([np.sin(ids), np.cos(ids)], axis=1)


@pytest.mark.parallel(ranks=[1, 2])
def test_halo_holds_every_partner_after_moves_below_half_the_skin():
    dim = 2
    domain = Domain(dim, 1.0 / 16, np.zeros(dim), np.ones(dim), periodic=(0,))
    values = cloud(dim, 600, seed=31)
    p = particle_set(dim, values, strided_share(values, domain))
    domain.decompose(p)
    ids, x = p["id"].copy(), p["x"].copy()
    halo = PDHalo(domain, REACH, SKIN)
    halo.build(x, {"id": ids, "x": x, "x0": reference_x(ids, x)})
    assert halo.builds == 1

    # Every particle moves by 0.45 skin (below skin/2): the plan stays valid.
    moved = x + displacement(ids, 0.45 * SKIN)
    assert halo.stale(moved) is False
    got = halo.refresh({"id": ids, "x": moved, "x0": reference_x(ids, x)})
    assert len(got["id"]) == halo.n_halo > 0
    # An image's x0 is shifted with its x: x - x0 is the particle's own displacement, up to
    # the rounding of adding the period (1.0) to both (a few ulps of 2: 4e-15 bounds it),
    # while an unshifted x0 is off by the whole period.
    all_ids = values["id"]
    all_moved = values["x"] + displacement(all_ids, 0.45 * SKIN)
    at = np.searchsorted(all_ids, got["id"])
    np.testing.assert_allclose(got["x"] - got["x0"],
                               all_moved[at] - reference_x(all_ids, values["x"])[at],
                               rtol=0, atol=4e-15)

    present = {(int(i),) + tuple(y) for i, y in zip(ids, moved)}
    present |= {(int(i),) + tuple(y) for i, y in zip(got["id"], got["x"])}
    shifts = domain.shifts * domain.dx  # physical image offsets: (0, 0), (-1, 0), (+1, 0)
    missing = 0
    for s in shifts:
        images = all_moved + s
        d2 = ((moved[:, None, :] - images[None, :, :]) ** 2).sum(axis=-1)
        for a, b in zip(*np.nonzero(d2 < REACH * REACH)):
            if (int(all_ids[b]),) + tuple(images[b]) not in present:
                missing += 1
    assert missing == 0

    # One particle of rank 0 moves 0.4 skin along both axes: 0.57 skin in distance, a
    # coordinate below skin/2. Every rank sees the plan stale.
    once = moved.copy()
    if domain.rank == 0 and len(once):
        once[0] = x[0] + 0.4 * SKIN
    assert halo.stale(once) is True


class _Rows:
    """The one `Bonds` verb `align_rows` calls, recorded."""

    def __init__(self):
        self.order = None

    def permute(self, order):
        self.order = np.asarray(order)


def test_align_rows_permutes_by_id_and_refuses_ids_it_does_not_hold():
    """Bond rows follow particle rows by id; an id with no bond row (a segment lost in
    transit) is an error at once, not a silent pairing with a neighbouring id's segment."""
    rows = _Rows()
    align_rows(rows, np.array([5, 3, 9]), np.array([9, 5, 3]))
    np.testing.assert_array_equal(rows.order, [2, 0, 1])
    # 4 sorts between held ids, 7 too; 10 beyond every held id and an empty holding were a
    # bare IndexError of the search before the documented error.
    for held, target in (([5, 3, 9], [3, 9, 4]), ([5, 3, 9], [3, 9, 5, 7]),
                         ([5, 3, 9], [3, 9, 10]), ([], [1])):
        rows = _Rows()
        with pytest.raises(RuntimeError, match="bond rows and particle rows hold different ids"):
            align_rows(rows, np.array(held, dtype=np.int64), np.array(target))
        assert rows.order is None

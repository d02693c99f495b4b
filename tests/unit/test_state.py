"""ParticleSet bookkeeping."""

import numpy as np

from hpcmpm.state import FieldSpec, ParticleSet, TENSOR


def test_remove_fills_holes_from_the_tail_and_keeps_every_field():
    p = ParticleSet(2, {"Fp": FieldSpec(TENSOR, "f8", "identity")})
    n = 20
    p.append({"id": np.arange(n), "x": np.arange(2 * n, dtype=float).reshape(n, 2)})
    p["Fp"][:] = np.arange(n)[:, None, None]
    gone = np.array([0, 3, 17, 19])
    p.remove(gone)
    assert p.n == n - len(gone)
    left = set(range(n)) - set(gone.tolist())
    assert set(p["id"].tolist()) == left
    for i, pid in enumerate(p["id"]):
        assert np.array_equal(p["x"][i], [2 * pid, 2 * pid + 1])
        assert np.all(p["Fp"][i] == pid)
    p.append({"id": np.array([99])})
    assert np.array_equal(p["Fp"][-1], np.eye(2))  # new rows get the fill, not stale data


def test_permute_and_keep():
    p = ParticleSet(3)
    p.append({"id": np.arange(5)})
    p.permute(np.array([4, 3, 2, 1, 0]))
    assert p["id"].tolist() == [4, 3, 2, 1, 0]
    p.keep(p["id"] % 2 == 0)
    assert p["id"].tolist() == [4, 2, 0]

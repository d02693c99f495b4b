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


def test_permute_in_place_matches_take_for_every_dtype_and_subsets():
    """The in-place cycle-following permute must equal ``np.take`` on every field (float
    tensors, int64 ids, int32 groups, bools), for full permutations and for subsets."""
    rng = np.random.default_rng(5)
    specs = {"Fp": FieldSpec(TENSOR, "f8", "identity"), "flag": FieldSpec("scalar", "?", False)}
    for n, m in ((1000, 1000), (1000, 377), (50, 0), (7, 7)):
        p = ParticleSet(3, specs)
        values = {"id": rng.permutation(10 * n)[:n], "group": rng.integers(0, 3, n),
                  "x": rng.random((n, 3)), "Fp": rng.random((n, 3, 3)),
                  "flag": rng.random(n) < 0.5}
        p.append(values)
        order = rng.permutation(n)[:m]
        p.permute(order)
        assert p.n == m
        for name, arr in values.items():
            assert np.array_equal(p[name], np.take(arr, order, axis=0)), (name, n, m)
        p.append({"id": np.array([-5])})  # rows past the new end were refilled
        assert np.array_equal(p["Fp"][-1], np.eye(3)) and not p["flag"][-1]

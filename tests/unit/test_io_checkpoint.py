"""Checkpoints: bitwise round trip on the same and other rank counts, keep-last-K, atomicity,
and damaged files reported as CheckpointError naming the file and the previous checkpoint."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from test_io_threadranks import run_ranks

from hpcmpm.errors import CheckpointError
from hpcmpm.io.checkpoint import (checkpoint_name, latest_checkpoint, read_checkpoint,
                                  write_checkpoint)
from hpcmpm.state import FieldSpec, ParticleSet
from launch import run_in_group

EXTRA = {"F": FieldSpec("tensor", "f8", "identity"), "tau": FieldSpec("tensor"),
         "Fp": FieldSpec("tensor", "f8", "identity"),
         "Jp": FieldSpec("scalar", "f8", 1.0), "flag": FieldSpec("scalar", "?", False),
         "label": FieldSpec("scalar", "i4", 0), "C": FieldSpec("tensor", "f4", 0.0)}


def rank_particles(dim: int, rank: int, size: int, n: int, empty_rank=None) -> ParticleSet:
    rng = np.random.default_rng(1000 + rank)
    count = 0 if rank == empty_rank else n + 7 * rank
    p = ParticleSet(dim, EXTRA)
    p.append({"id": rank * 100_000 + rng.permutation(count), "x": rng.random((count, dim)),
              "v": rng.standard_normal((count, dim)), "group": rng.integers(0, 4, count),
              "F": rng.standard_normal((count, dim, dim)), "flag": rng.random(count) < 0.5,
              "label": rng.integers(-5, 5, count), "C": rng.random((count, dim, dim)),
              "tau": rng.standard_normal((count, dim, dim)), "mass": rng.random(count),
              "vol0": rng.random(count), "Jp": rng.random(count)})
    return p


def meta(step: int, size: int) -> dict:
    return {"step": step, "time": step * 1e-3, "frame_index": 4, "last_dt": 1e-3 / 3,
            "scene_text": 'name = "ckpt"\n', "restart_chain": ["a.toml"], "n_ranks": size,
            "rng_state": {"bit_generator": "PCG64", "state": {"state": 2**100 + 1}},
            "boxes": np.arange(size * 6, dtype=np.int64).reshape(size, 2, 3),
            "hpcmpm_version": "0.1.0"}


def write(folder, size, step=100, keep=2, dim=3, n=60, empty_rank=None, chunk_bytes=4096):
    def body(comm):
        p = rank_particles(dim, comm.rank, comm.size, n, empty_rank)
        path = write_checkpoint(folder, comm, p, meta(step, comm.size), keep=keep,
                                mode="serial", chunk_bytes=chunk_bytes)
        return path, p.snapshot()

    results = run_ranks(size, body)
    return results[0][0], [snap for _, snap in results]


def read(path, size):
    return run_ranks(size, lambda comm: read_checkpoint(path, comm))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("size,empty_rank", [(1, None), (2, None), (2, 0), (3, 1)])
def test_round_trip_same_rank_count_is_bitwise(tmp_path, dim, size, empty_rank):
    path, written = write(tmp_path, size, dim=dim, empty_rank=empty_rank)
    assert path.name == checkpoint_name(100) == "ckpt_000000100.h5"
    for (fields, got_meta), want in zip(read(path, size), written):
        assert sorted(fields) == sorted(want)
        for name, arr in want.items():
            assert fields[name].dtype == arr.dtype and fields[name].shape == arr.shape
            assert fields[name].tobytes() == arr.tobytes(), name
        assert got_meta["rng_state"] == meta(100, size)["rng_state"]
        assert got_meta["last_dt"] == 1e-3 / 3 and got_meta["restart_chain"] == ["a.toml"]
        np.testing.assert_array_equal(got_meta["boxes"], meta(100, size)["boxes"])
        assert got_meta["boxes"].dtype == np.int64


@pytest.mark.parametrize("write_size,read_size", [(2, 3), (3, 1), (1, 2)])
def test_read_on_another_rank_count_splits_rows_evenly(tmp_path, write_size, read_size):
    path, written = write(tmp_path, write_size)
    shares = [fields for fields, _ in read(path, read_size)]
    counts = [len(f["id"]) for f in shares]
    assert max(counts) - min(counts) <= 1
    for name in written[0]:
        whole = np.concatenate([s[name] for s in shares])
        np.testing.assert_array_equal(whole, np.concatenate([w[name] for w in written]))


def test_keep_last_k_and_latest(tmp_path):
    for step in (100, 200, 300, 400):
        write(tmp_path, 2, step=step, keep=3)
    assert sorted(p.name for p in tmp_path.glob("ckpt_*")) == [
        checkpoint_name(s) for s in (200, 300, 400)]
    write(tmp_path, 1, step=500, keep=1)
    assert [p.name for p in tmp_path.glob("ckpt_*")] == [checkpoint_name(500)]
    # A partial write (crash before rename) is never picked.
    (tmp_path / (checkpoint_name(900) + ".tmp")).write_bytes(b"\x89HDF partial")
    assert latest_checkpoint(tmp_path) == tmp_path / checkpoint_name(500)
    assert latest_checkpoint(tmp_path / "nowhere") is None
    assert not list(tmp_path.glob("*.h5.tmp"))[1:]  # only the planted one


def test_keep_leaves_newer_steps_of_another_timeline(tmp_path):
    write(tmp_path, 1, step=300)
    write(tmp_path, 1, step=100)
    assert sorted(p.name for p in tmp_path.glob("ckpt_*")) == [
        checkpoint_name(100), checkpoint_name(300)]


def test_truncated_file_names_file_and_previous(tmp_path):
    write(tmp_path, 2, step=100)
    path, _ = write(tmp_path, 2, step=200)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError) as err:
        read(path, 2)
    message = str(err.value)
    assert "ckpt_000000200.h5" in message and "truncated" in message
    assert "previous checkpoint ckpt_000000100.h5 may still be usable" in message
    assert "\n" not in message
    read(tmp_path / checkpoint_name(100), 2)  # the previous one still loads


def flip_bytes_in(path, dataset: str, where: int = 5) -> None:
    with h5py.File(path, "r") as h5:
        offset = h5[dataset].id.get_offset()
    with open(path, "r+b") as f:
        f.seek(offset + where)
        byte = f.read(1)
        f.seek(offset + where)
        f.write(bytes([byte[0] ^ 0x5A]))


@pytest.mark.parametrize("dataset", ["/particles/x", "/particles/flag", "/meta/boxes"])
@pytest.mark.parametrize("read_size", [1, 2])
def test_corrupted_bytes_are_detected(tmp_path, dataset, read_size):
    write(tmp_path, 2, step=100)
    path, _ = write(tmp_path, 2, step=200)
    flip_bytes_in(path, dataset)
    with pytest.raises(CheckpointError) as err:
        read(path, read_size)
    assert str(err.value) == (f"ckpt_000000200.h5: checksum mismatch in {dataset}: file is "
                              "corrupt; the previous checkpoint ckpt_000000100.h5 may still "
                              "be usable")
    read(tmp_path / checkpoint_name(100), read_size)


def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(CheckpointError, match="no such checkpoint; .* holds no checkpoint$"):
        read(tmp_path / "ckpt_000000001.h5", 1)
    with pytest.raises(CheckpointError, match=r"no such checkpoint \(no folder .*nope\)$"):
        read(tmp_path / "nope" / "ckpt_000000001.h5", 1)
    foreign = tmp_path / "ckpt_000000002.h5"
    with h5py.File(foreign, "w") as h5:
        h5["x"] = 1
    with pytest.raises(CheckpointError, match="not an hpcmpm checkpoint"):
        read(foreign, 1)
    text = tmp_path / "ckpt_000000003.h5"
    text.write_text("hello")
    with pytest.raises(CheckpointError, match="ckpt_000000003.h5: not a readable HDF5 file"):
        read(text, 2)


def test_missing_checkpoint_names_the_ones_there(tmp_path):
    # A run without checkpoint_every writes only its last checkpoint: a user who guesses
    # another step's name is told which ones exist, not only which are "earlier".
    for step in (100, 200, 300, 400):
        write(tmp_path, 1, step=step, keep=10)
    with pytest.raises(CheckpointError) as err:
        read(tmp_path / checkpoint_name(250), 1)
    assert str(err.value) == (f"{tmp_path / checkpoint_name(250)}: no such checkpoint; "
                              f"{tmp_path} holds ckpt_000000200.h5, ckpt_000000300.h5, "
                              "ckpt_000000400.h5 and 1 earlier")


def test_unwritable_folder_is_a_checkpoint_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(CheckpointError, match="cannot"):
        write(blocker / "sub", 2)


def test_fluid_checkpoint_holding_F_restarts_with_J(tmp_path, monkeypatch):
    """A checkpoint of a fluid-only scene written when particles still carried F (before J
    alone) restarts with J = det F, not with the fill value 1."""
    import sys
    from pathlib import Path

    from hpcmpm import runner
    from hpcmpm.io import checkpoint
    from hpcmpm.parallel import Communicator

    out = tmp_path / "dam"
    exe = Path(sys.executable).with_name("hpcmpm")
    proc = run_in_group([str(exe), "run", "inputs/dam_break_2d.toml", "--out", str(out),
                         "--quiet", "--set", "simulation.end_time=0.05"], timeout=300)
    assert proc.returncode == 0, proc.stderr
    ckpt = latest_checkpoint(out)
    fields, _ = read_checkpoint(ckpt, Communicator())
    J = fields["J"].copy()
    assert np.abs(J - 1.0).max() > 1e-4  # the column has compressed: 1 would be wrong

    original = checkpoint.read_checkpoint

    def with_F_instead_of_J(path, comm):
        old, meta = original(path, comm)
        j = old.pop("J")
        old["F"] = np.sqrt(j)[:, None, None] * np.eye(2)  # the fluid's isotropic F, det = J
        return old, meta

    monkeypatch.setattr(checkpoint, "read_checkpoint", with_F_instead_of_J)
    sim, _, _ = runner.restore_simulation(str(ckpt), Communicator(), None)
    order = np.argsort(sim.particles["id"])
    assert "F" not in sim.particles
    # det of sqrt(J) I in floating point: equal to J within a few ulps.
    assert np.allclose(sim.particles["J"][order], J[np.argsort(fields["id"])], rtol=1e-14,
                       atol=0)


def test_checksum_covers_every_chunk_and_combines_across_a_split():
    """`hpcmpm.io.checksum` sums its words in passes of ``_CHUNK`` (2**20); the checkpoints
    above are far smaller than one pass, so a pass that skipped the words after the first
    would go unnoticed there. A (600000, 3) float64 array is 1.8 M words (two passes): a
    one-ulp change of its LAST element must change the checksum, and the array split at row
    250000 into two slices, each checksummed from its first row and combined the way the
    writer combines the ranks' slices (write_checkpoint: partial_checksum(rows, offset),
    then combine), must give the whole array's checksum. The second slice (1.05 M words)
    spans two passes itself. Exact equalities: the sum is integer arithmetic mod 2**64."""
    from hpcmpm.io import checksum as cks

    rows, split = 600_000, 250_000
    assert rows * 3 > cks._CHUNK and (rows - split) * 3 > cks._CHUNK
    a = np.random.default_rng(7).standard_normal((rows, 3))
    whole = cks.checksum(a)
    changed = a.copy()
    changed[-1, -1] = np.nextafter(changed[-1, -1], np.inf)
    assert cks.checksum(changed) != whole
    parts = [cks.partial_checksum(a[:split], 0), cks.partial_checksum(a[split:], split)]
    assert cks.combine(parts) == whole
    # The split is not an identity by accident: the second slice counted from row 0 is
    # another sum (the element index enters every term).
    assert cks.combine([parts[0], cks.partial_checksum(a[split:], 0)]) != whole


def test_a_dataset_with_the_wrong_row_count_is_reported(tmp_path):
    """A /particles dataset shorter than n_particles (a damaged or hand-edited file) is named
    as such, with its row count, instead of surfacing as a checksum mismatch or a short
    share. The dataset is rewritten one row short with its original checksum attribute."""
    write(tmp_path, 2, step=100)
    path, written = write(tmp_path, 2, step=200)
    n = sum(len(w["id"]) for w in written)
    with h5py.File(path, "r+") as h5:
        old = h5["particles/mass"]
        data, checksum = old[:-1], old.attrs["checksum"]
        del h5["particles/mass"]
        h5["particles/mass"] = data
        h5["particles/mass"].attrs["checksum"] = checksum
    with pytest.raises(CheckpointError) as err:
        read(path, 2)
    assert str(err.value) == (f"ckpt_000000200.h5: /particles/mass has {n - 1} rows, expected "
                              f"{n}: file is corrupt; the previous checkpoint "
                              "ckpt_000000100.h5 may still be usable")


def test_root_attributes_describe_the_checkpoint(tmp_path):
    """Provenance a user reads with h5dump or `hpcmpm info`, not used by the restart itself
    (which reads ``meta``): a dropped or constant attribute would go unnoticed by every
    round trip above."""
    path, written = write(tmp_path, 3, step=300, dim=2)
    with h5py.File(path, "r") as h5:
        attrs = dict(h5.attrs)
    assert attrs["kind"] == "checkpoint" and attrs["format"] == 1
    assert attrs["step"] == 300 and attrs["time"] == 300 * 1e-3 and attrs["dim"] == 2
    assert attrs["n_particles"] == sum(len(w["id"]) for w in written)
    assert attrs["n_ranks"] == 3 and attrs["io_mode"] == "serial"
    assert attrs["scene"] == 'name = "ckpt"\n' and attrs["hpcmpm_version"] == "0.1.0"
    assert attrs["restart_chain"] == '["a.toml"]'
    assert attrs["checksum_algorithm"] == "splitmix64-sum"


def test_a_frame_of_a_checkpointed_step_names_that_checkpoint(tmp_path):
    """The last frame and the last checkpoint of a run share their step: restarting from the
    frame names the checkpoint of that very step (at or before it), not the one before."""
    for step in (100, 200, 300):
        write(tmp_path, 1, step=step, keep=5)
    frame = tmp_path / "frame_000004.h5"
    with h5py.File(frame, "w") as h5:
        h5.attrs["kind"] = "frame"
        h5.attrs["step"] = 200
    with pytest.raises(CheckpointError) as err:
        read(frame, 1)
    assert str(err.value).endswith(
        f"the newest checkpoint at or before its step 200 is {tmp_path / checkpoint_name(200)}")


def test_checkpoint_reaches_the_disk_before_its_name_and_the_folder_after(tmp_path,
                                                                            monkeypatch):
    """The module's crash guarantee (at least one complete checkpoint at any moment) needs
    the data fsynced before the rename and the folder fsynced after it; neither shows in a
    test that does not crash the machine, so the calls are recorded: fsync of the .tmp
    file, rename to the final name, fsync of the folder, in that order."""
    import os

    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", str(src), str(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    path, _ = write(tmp_path, 1, step=100)
    tmp = str(path) + ".tmp"
    assert events == [("fsync", tmp), ("replace", tmp, str(path)), ("fsync", str(tmp_path))]

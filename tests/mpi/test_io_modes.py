"""Frames and checkpoints under a real MPI launch, in serial mode and (where h5py has parallel
HDF5) in mpio mode: the same data gives the same file, a rank without particles included.

Runs at any rank count; the `parallel` marker (tests/conftest.py) runs it on 1 rank and
re-runs it under ``mpiexec -n 2``. By hand:
    timeout 120 mpiexec -n 2 python -m mpi4py -m pytest -q tests/mpi/test_io_modes.py
In .venv-mpio (scripts/setup_parallel_hdf5.sh) the mpio cases run too.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from hpcmpm.io.checkpoint import read_checkpoint, write_checkpoint
from hpcmpm.io.frames import FrameWriter, read_frame
from hpcmpm.parallel.comm import Communicator
from hpcmpm.state import FieldSpec, ParticleSet

MPIO = bool(h5py.get_config().mpi)
needs_mpio = pytest.mark.skipif(
    not MPIO, reason="h5py built without MPI (serial PyPI wheel); run "
                     "scripts/setup_parallel_hdf5.sh")
pytestmark = [pytest.mark.parallel(ranks=[1, 2]), pytest.mark.timeout(120)]
N = 3001


@pytest.fixture
def comm():
    return Communicator()


@pytest.fixture
def shared_dir(shared_tmp) -> Path:
    return shared_tmp


def global_values(dim: int, gaps: bool) -> dict:
    rng = np.random.default_rng(42)
    ids = rng.permutation(N).astype(np.int64) * (5 if gaps else 1)
    return {"id": ids, "group": (ids % 4).astype(np.int32), "x": rng.random((N, dim)),
            "v": rng.standard_normal((N, dim)), "mass": rng.random(N),
            "F": rng.standard_normal((N, dim, dim)), "Jp": rng.random(N),
            "flag": rng.random(N) < 0.3}


def local_particles(comm, dim: int, gaps: bool = False, empty_last: bool = True) -> ParticleSet:
    """A strided share of the global set (every id its own run of rows: more runs than one
    mpio write takes); with ``empty_last`` the last rank holds nothing when size > 1."""
    values = global_values(dim, gaps)
    holders = max(1, comm.size - 1) if empty_last else comm.size
    mine = (np.arange(N) % holders == comm.rank) if comm.rank < holders else np.zeros(N, bool)
    p = ParticleSet(dim, {"Jp": FieldSpec(), "flag": FieldSpec("scalar", "?", False),
                          "F": FieldSpec("tensor", "f8", "identity")})
    p.append({k: v[mine] for k, v in values.items()})
    return p


def write_frame(comm, folder: Path, mode: str, dim: int, gaps: bool = False,
                empty_last: bool = True) -> Path:
    writer = FrameWriter(folder, comm, "name = 'modes'\n", dim, ["Jp"], {"restart_chain": []},
                         mode=mode, chunk_bytes=50_000)
    return writer.write(local_particles(comm, dim, gaps, empty_last), 0.5, 12)


def check_frame(path: Path, dim: int, gaps: bool) -> dict:
    values = global_values(dim, gaps)
    order = np.argsort(values["id"])
    data, attrs = read_frame(path)
    assert attrs["n_particles"] == N and attrs["dim"] == dim
    np.testing.assert_array_equal(data["id"], values["id"][order])
    for name in ("x", "v", "F", "mass", "Jp"):
        np.testing.assert_array_equal(data[name], values[name][order], err_msg=name)
    np.testing.assert_array_equal(data["material"], values["group"][order])
    return data


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("gaps", [False, True])
@pytest.mark.parametrize("empty_last", [True, False])
def test_serial_mode_frame(comm, shared_dir, dim, gaps, empty_last):
    path = write_frame(comm, shared_dir, "serial", dim, gaps, empty_last)
    if comm.rank == 0:
        check_frame(path, dim, gaps)
    comm.barrier()


@needs_mpio
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("gaps", [False, True])
@pytest.mark.parametrize("empty_last", [True, False])
def test_mpio_frame_equals_serial_frame(comm, shared_dir, dim, gaps, empty_last):
    serial = write_frame(comm, shared_dir / "serial", "serial", dim, gaps, empty_last)
    mpio = write_frame(comm, shared_dir / "mpio", "mpio", dim, gaps, empty_last)
    if comm.rank == 0:
        a, b = check_frame(serial, dim, gaps), check_frame(mpio, dim, gaps)
        assert sorted(a) == sorted(b)
        for name in a:
            assert a[name].tobytes() == b[name].tobytes(), name
        with h5py.File(mpio) as h5:
            assert h5.attrs["io_mode"] == "mpio"
    comm.barrier()


def checkpoint_round_trip(comm, folder: Path, write_mode: str) -> None:
    p = local_particles(comm, 3)
    meta = {"step": 7, "time": 0.25, "boxes": np.arange(6.0), "n_ranks": comm.size}
    path = write_checkpoint(folder, comm, p, meta, mode=write_mode, chunk_bytes=30_000)
    fields, got = read_checkpoint(path, comm)
    for name in p.field_names():
        assert fields[name].tobytes() == p[name].tobytes(), name
    assert got["step"] == 7 and got["boxes"].tolist() == list(range(6))


def test_serial_mode_checkpoint(comm, shared_dir):
    checkpoint_round_trip(comm, shared_dir, "serial")


@needs_mpio
def test_mpio_checkpoint_equals_serial_checkpoint(comm, shared_dir):
    checkpoint_round_trip(comm, shared_dir / "serial", "mpio")
    checkpoint_round_trip(comm, shared_dir / "mpio", "mpio")
    if comm.rank == 0:
        with h5py.File(shared_dir / "serial" / "ckpt_000000007.h5") as a, \
                h5py.File(shared_dir / "mpio" / "ckpt_000000007.h5") as b:
            for name in a["particles"]:
                assert a["particles"][name][...].tobytes() == b["particles"][name][...].tobytes()
                assert a["particles"][name].attrs["checksum"] == \
                    b["particles"][name].attrs["checksum"]
    comm.barrier()


@pytest.mark.parametrize("mode", ["serial", pytest.param("mpio", marks=needs_mpio)])
@pytest.mark.parametrize("what", ["frame", "checkpoint"])
def test_a_write_failure_on_one_rank_is_raised_on_every_rank(comm, shared_dir, monkeypatch,
                                                             mode, what):
    """No abort hook here: the failing rank keeps to the protocol and the file's commit raises
    the same error everywhere. Without that, the other ranks would wait in a collective until
    the harness killed the launch."""
    import hpcmpm.io.shared as shared
    from hpcmpm.errors import CheckpointError, FrameError

    # Serial mode: rank 0 writes everything; mpio: the last rank's share fails.
    failing = 0 if mode == "serial" else comm.size - 1
    if comm.rank == failing:
        def no_space(*args, **kwargs):
            raise OSError("No space left on device (injected)")

        if mode == "serial":
            monkeypatch.setattr(h5py.Dataset, "__setitem__", no_space)
        else:
            monkeypatch.setattr(shared.SharedFile, "_selection", staticmethod(no_space))
    folder = shared_dir / f"{what}-{mode}"
    with pytest.raises(FrameError if what == "frame" else CheckpointError,
                       match="No space left on device") as info:
        if what == "frame":
            write_frame(comm, folder, mode, 3, gaps=True, empty_last=False)
        else:
            p = local_particles(comm, 3, empty_last=False)
            write_checkpoint(folder, comm, p, {"step": 3, "time": 0.1}, mode=mode)
    assert "\n" not in str(info.value)
    comm.barrier()
    assert sorted(f.name for f in folder.iterdir() if f.suffix in (".h5", ".tmp")) == []

"""Frames: round trip in 2D/3D on 1 and several (thread) ranks, a rank without particles,
rank-count independence, atomic write, provenance."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from test_io_threadranks import run_ranks

from hpcmpm.io.frames import FrameWriter, frame_name, read_frame
from hpcmpm.state import FieldSpec, ParticleSet

SCENE = 'name = "frame test"\ndim = 3\n'


def global_particles(dim: int, n: int, seed: int = 0, gaps: bool = False) -> dict:
    rng = np.random.default_rng(seed)
    ids = rng.permutation(n).astype(np.int64)
    if gaps:
        ids = ids * 3 + 7  # unique, not dense
    return {"id": ids, "group": (ids % 3).astype(np.int32), "x": rng.random((n, dim)),
            "v": rng.standard_normal((n, dim)), "mass": rng.random(n),
            "F": np.eye(dim) + 0.1 * rng.standard_normal((n, dim, dim)),
            "Jp": rng.random(n)}


def share(values: dict, rank: int, size: int, empty_rank: int | None) -> dict:
    """Rank ``rank``'s particles: a strided share, none on ``empty_rank``."""
    owners = np.arange(len(values["id"])) % max(1, size - (empty_rank is not None))
    if empty_rank is not None:
        owners[owners >= empty_rank] += 1
    mine = owners == rank
    return {k: v[mine] for k, v in values.items()}


def particle_set(dim: int, values: dict) -> ParticleSet:
    p = ParticleSet(dim, {"Jp": FieldSpec(), "F": FieldSpec("tensor", "f8", "identity")})
    p.append(values)
    return p


def write_frames(out_dir, values, dim, size, empty_rank=None, chunk_bytes=2048, times=(0.0,)):
    def body(comm):
        p = particle_set(dim, share(values, comm.rank, comm.size, empty_rank))
        w = FrameWriter(out_dir, comm, SCENE, dim, ["Jp", "missing_field"],
                        {"restart_chain": ["a.toml"]}, mode="serial", chunk_bytes=chunk_bytes)
        return [str(w.write(p, t, 10 * i, {"kinetic_energy": 1.5})) for i, t in enumerate(times)]

    return run_ranks(size, body)[0]


def expected_rows(values):
    order = np.argsort(values["id"])
    return {"id": values["id"][order], "x": values["x"][order], "v": values["v"][order],
            "F": values["F"][order], "mass": values["mass"][order],
            "material": values["group"][order], "Jp": values["Jp"][order]}


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("size,empty_rank", [(1, None), (2, None), (2, 1), (3, 0)])
def test_frame_round_trip(tmp_path, dim, size, empty_rank):
    values = global_particles(dim, 257, seed=dim)
    paths = write_frames(tmp_path, values, dim, size, empty_rank)
    data, attrs = read_frame(paths[0])
    want = expected_rows(values)
    assert sorted(data) == sorted(want)
    for name, arr in want.items():
        np.testing.assert_array_equal(data[name], arr, err_msg=name)
    assert data["id"].dtype == np.int64 and data["material"].dtype == np.int32
    assert data["F"].shape == (257, dim, dim)
    assert attrs["dim"] == dim and attrs["n_particles"] == 257 and attrs["n_ranks"] == size
    assert attrs["time"] == 0.0 and attrs["step"] == 0 and attrs["scene"] == SCENE
    assert attrs["restart_chain"] == '["a.toml"]' and attrs["kinetic_energy"] == 1.5
    assert attrs["hpcmpm_version"]


@pytest.mark.parametrize("gaps", [False, True])
def test_frame_files_do_not_depend_on_rank_count(tmp_path, gaps):
    values = global_particles(3, 1000, seed=5, gaps=gaps)
    files = [write_frames(tmp_path / f"r{size}", values, 3, size, empty, chunk_bytes=chunk)[0]
             for size, empty, chunk in [(1, None, 1 << 20), (2, None, 3000), (3, 1, 700)]]
    reference, _ = read_frame(files[0])
    for other in files[1:]:
        data, _ = read_frame(other)
        for name in reference:
            np.testing.assert_array_equal(data[name], reference[name], err_msg=name)


def test_frames_are_numbered_atomic_and_continue_after_restart(tmp_path):
    values = global_particles(2, 50)
    paths = write_frames(tmp_path, values, 2, 2, times=(0.0, 0.5, 1.0))
    assert [p.rsplit("/", 1)[1] for p in paths] == [frame_name(i) for i in range(3)]
    assert not list(tmp_path.glob("*.tmp"))

    def resumed(comm):
        p = particle_set(2, share(values, comm.rank, comm.size, None))
        w = FrameWriter(tmp_path, comm, SCENE, 2, [], {"restart_chain": []}, first_frame=3)
        return str(w.write(p, 1.5, 40))

    assert run_ranks(1, resumed)[0].endswith(frame_name(3))
    assert sorted(p.name for p in tmp_path.glob("frame_*.h5")) == [frame_name(i) for i in range(4)]


def test_zero_particles_everywhere(tmp_path):
    values = {k: v[:0] for k, v in global_particles(3, 4).items()}
    data, attrs = read_frame(write_frames(tmp_path, values, 3, 2)[0])
    assert attrs["n_particles"] == 0 and data["x"].shape == (0, 3)


def test_long_scene_text_fits_in_an_attribute(tmp_path):
    text = "# " + "x" * 200_000 + "\n"

    def body(comm):
        p = particle_set(3, global_particles(3, 5))
        return FrameWriter(tmp_path, comm, text, 3, [], {"restart_chain": []}).write(p, 0.0, 0)

    path = run_ranks(1, body)[0]
    with h5py.File(path) as h5:
        assert h5.attrs["scene"] == text


def test_every_frame_carries_its_own_time_step_and_provenance(tmp_path):
    """The round trip above writes one frame at time 0, step 0, index 0: an attribute taken
    from the wrong source (the frame index for the step) would pass there. Here frame 2 is
    step 20 at t = 1, and an extra attribute that reuses a core name does not replace it.
    Numpy scalars among the extras are stored as numbers, not as JSON text."""
    values = global_particles(2, 30)

    def body(comm):
        p = particle_set(2, share(values, comm.rank, comm.size, None))
        w = FrameWriter(tmp_path, comm, SCENE, 2, [], {"restart_chain": ["a.toml", "b.h5"],
                                                       "scene_path": "inputs/x.toml"},
                        mode="serial")
        extra = {"time": -1.0, "step": -1, "energy": 2.5, "count": np.int64(7),
                 "ratio": np.float32(0.25)}
        return [str(w.write(p, t, s, extra))
                for t, s in ((0.0, 0), (0.5, 10), (1.0, 20))]

    paths = run_ranks(2, body)[0]
    for index, (path, t, s) in enumerate(zip(paths, (0.0, 0.5, 1.0), (0, 10, 20))):
        _, attrs = read_frame(path)
        assert (attrs["time"], attrs["step"], attrs["frame_index"]) == (t, s, index)
        assert attrs["energy"] == 2.5 and attrs["scene_path"] == "inputs/x.toml"
        assert attrs["count"] == 7 and attrs["ratio"] == 0.25
        assert attrs["restart_chain"] == '["a.toml", "b.h5"]' and attrs["n_ranks"] == 2


def test_io_mode_none_reads_the_environment(monkeypatch):
    """``mode=None`` (the runner's default) takes $HPCMPM_IO_MODE (docs/output.md); an explicit
    mode wins over it, and a wrong value is refused whichever way it came."""
    from types import SimpleNamespace

    from hpcmpm.errors import HpcmpmError
    from hpcmpm.io.shared import mpio_available, resolve_mode

    two_ranks = SimpleNamespace(size=2, rank=0)
    monkeypatch.setenv("HPCMPM_IO_MODE", "serial")
    assert resolve_mode(None, two_ranks) == "serial"
    monkeypatch.setenv("HPCMPM_IO_MODE", "parallel")
    with pytest.raises(HpcmpmError, match="I/O mode 'parallel': must be one of auto, serial, "
                                          "mpio"):
        resolve_mode(None, two_ranks)
    assert resolve_mode("serial", two_ranks) == "serial"
    monkeypatch.setenv("HPCMPM_IO_MODE", "mpio")
    if mpio_available():
        assert resolve_mode(None, two_ranks) == "mpio"
    else:
        with pytest.raises(HpcmpmError, match="needs h5py built with MPI"):
            resolve_mode(None, two_ranks)
    monkeypatch.delenv("HPCMPM_IO_MODE")
    assert resolve_mode(None, two_ranks) == ("mpio" if mpio_available() else "serial")

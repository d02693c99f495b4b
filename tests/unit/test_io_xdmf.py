"""particles.xdmf: valid XDMF 3 whose every DataItem names an existing dataset of the stated
dimensions, one grid per frame on disk, relative paths, a Polyvertex connectivity 0..n-1 (without
it ParaView builds no cells: tests/unit/test_io_paraview.py)."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_io_frames import global_particles, particle_set, share, write_frames
from test_io_threadranks import run_ranks

from hpcmpm.io import xdmf
from hpcmpm.io.frames import FrameWriter


def check_xdmf(path: Path) -> list[tuple[float, int]]:
    """Parse ``path``, check every reference; return (time, n_points) per grid."""
    root = ET.parse(path).getroot()
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    collection = root.find("Domain/Grid")
    assert collection.get("GridType") == "Collection"
    assert collection.get("CollectionType") == "Temporal"
    steps = []
    for grid in collection.findall("Grid"):
        assert grid.get("GridType") == "Uniform"
        n = int(grid.find("Topology").get("NumberOfElements"))
        assert grid.find("Topology").get("TopologyType") == "Polyvertex"
        connectivity = grid.find("Topology/DataItem")
        file, dataset = connectivity.text.strip().split(":")
        with h5py.File(path.parent / file, "r") as h5:
            np.testing.assert_array_equal(h5[dataset][...], np.arange(n))
        for item in grid.iter("DataItem"):
            file, dataset = item.text.strip().split(":")
            assert not Path(file).is_absolute()
            with h5py.File(path.parent / file, "r") as h5:
                dset = h5[dataset]
                dims = tuple(int(s) for s in item.get("Dimensions").split())
                assert dims == dset.shape, (file, dataset)
                assert dims[0] == n
                assert int(item.get("Precision")) == dset.dtype.itemsize
                kind = {"f": "Float", "i": "Int"}[dset.dtype.kind]
                assert item.get("NumberType") == kind
        steps.append((float(grid.find("Time").get("Value")), n))
    return steps


@pytest.mark.parametrize("dim", [2, 3])
def test_xdmf_references_every_frame(tmp_path, dim):
    values = global_particles(dim, 40)
    write_frames(tmp_path, values, dim, 2, times=(0.0, 0.25, 0.5))
    assert check_xdmf(tmp_path / "particles.xdmf") == [(0.0, 40), (0.25, 40), (0.5, 40)]
    root = ET.parse(tmp_path / "particles.xdmf").getroot()
    grid = root.find("Domain/Grid/Grid")
    assert grid.find("Geometry").get("GeometryType") == ("XYZ" if dim == 3 else "XY")
    types = {a.get("Name"): a.get("AttributeType") for a in grid.findall("Attribute")}
    # One value per particle: node-centred (a Cell centre would bind them to the vertex cells,
    # which ParaView's point filters and the Points representation do not see).
    assert {a.get("Center") for a in grid.findall("Attribute")} == {"Node"}
    assert types == {"id": "Scalar", "v": "Vector", "F": "Tensor" if dim == 3 else "Matrix",
                     "mass": "Scalar", "material": "Scalar", "Jp": "Scalar"}
    # The folder can be moved: references are relative.
    moved = tmp_path.parent / (tmp_path.name + "_moved")
    shutil.copytree(tmp_path, moved)
    assert len(check_xdmf(moved / "particles.xdmf")) == 3


def test_xdmf_lists_exactly_the_frames_on_disk(tmp_path):
    values = global_particles(3, 10)
    write_frames(tmp_path, values, 3, 1, times=(0.0, 1.0))
    (tmp_path / "frame_000000.h5").unlink()
    (tmp_path / "frame_000005.h5.tmp").write_bytes(b"partial")
    # A complete file left under its temporary name (a crash between close and rename) is
    # readable, yet no frame either.
    shutil.copy(tmp_path / "frame_000001.h5", tmp_path / "frame_000006.h5.tmp")
    # A file with a frame's name that is no frame (no attributes) is left out, not fatal.
    with h5py.File(tmp_path / "frame_000007.h5", "w") as h5:
        h5["particles/x"] = np.zeros((2, 3))

    def resumed(comm):  # a restart into the same folder picks up frame 1 from disk
        p = particle_set(3, share(values, comm.rank, comm.size, None))
        FrameWriter(tmp_path, comm, "", 3, [], {"restart_chain": []}, first_frame=2).write(
            p, 2.0, 7)

    run_ranks(1, resumed)
    assert check_xdmf(tmp_path / "particles.xdmf") == [(1.0, 10), (2.0, 10)]
    assert not (tmp_path / "particles.xdmf.tmp").exists()


def test_time_values_keep_full_precision(tmp_path):
    t = 0.1 + 0.2
    values = global_particles(3, 3)
    write_frames(tmp_path, values, 3, 1, times=(t,))
    assert check_xdmf(tmp_path / "particles.xdmf")[0][0] == t
    assert np.float64(t) == t


def test_connectivity_is_0_to_n_minus_1_across_write_chunks(tmp_path, monkeypatch):
    """`write_connectivity` writes 0..n-1 in pieces of CONNECTIVITY_CHUNK rows (2**24: no
    frame of the tests reaches a second piece); a chunk of 7 rows makes 30 rows 5 pieces,
    the last one short."""
    monkeypatch.setattr(xdmf, "CONNECTIVITY_CHUNK", 7)
    path = xdmf.write_connectivity(tmp_path, 30)
    with h5py.File(path, "r") as h5:
        np.testing.assert_array_equal(h5[xdmf.CONNECTIVITY_DATASET][...], np.arange(30))


def test_connectivity_dtype_holds_every_index_and_is_int32_when_it_can():
    for n in (1, 2**31 - 1, 2**31, 2**31 + 1, 2**32 + 5):
        assert np.iinfo(xdmf.connectivity_dtype(n)).max >= n - 1, n
    assert xdmf.connectivity_dtype(2**31 - 1) == np.int32  # 4 B a particle below 2**31


def test_number_types_keep_sign_and_size():
    """An unsigned dataset described as signed reads back wrapped (uint16 40000 as -25536)."""
    assert xdmf.number_type(np.uint8) == ("UChar", 1)
    assert xdmf.number_type(np.uint16) == ("UInt", 2)
    assert xdmf.number_type(np.uint32) == ("UInt", 4)
    assert xdmf.number_type(np.int8) == ("Char", 1)
    assert xdmf.number_type(np.int32) == ("Int", 4)
    assert xdmf.number_type(np.float32) == ("Float", 4)
    with pytest.raises(ValueError, match="no XDMF number type"):
        xdmf.number_type(np.complex128)


def test_a_failed_rewrite_leaves_the_previous_xdmf_whole(tmp_path, monkeypatch):
    """particles.xdmf is rewritten after every frame while ParaView may be reading it: the
    text goes to a temporary file renamed over the old one, so a write that fails half way
    (disk full) leaves the previous file intact rather than half an XML document."""
    from hpcmpm.io.xdmf import FrameCatalog

    write_frames(tmp_path, global_particles(3, 10), 3, 1, times=(0.0, 1.0))
    target = tmp_path / "particles.xdmf"
    before = target.read_text()
    real_write_text = Path.write_text

    def half_then_fail(self, text, *args, **kwargs):
        real_write_text(self, text[: len(text) // 2], *args, **kwargs)
        raise OSError("No space left on device (injected)")

    monkeypatch.setattr(Path, "write_text", half_then_fail)
    with pytest.raises(OSError, match="injected"):
        FrameCatalog(tmp_path).write()
    assert target.read_text() == before
    assert check_xdmf(target) == [(0.0, 10), (1.0, 10)]


def test_frames_deleted_during_a_run_leave_the_xdmf(tmp_path):
    """A user who removes early frames of a long run (disk space) while it runs: the next
    frame's rewrite lists the frames still on disk, without the removed one's grid."""
    values = global_particles(3, 12)

    def body(comm):
        p = particle_set(3, share(values, comm.rank, comm.size, None))
        w = FrameWriter(tmp_path, comm, "", 3, [], {"restart_chain": []}, mode="serial")
        w.write(p, 0.0, 0)
        w.write(p, 0.5, 5)
        comm.barrier()
        if comm.rank == 0:
            (tmp_path / "frame_000000.h5").unlink()
        comm.barrier()
        w.write(p, 1.0, 10)

    run_ranks(2, body)
    assert check_xdmf(tmp_path / "particles.xdmf") == [(0.5, 12), (1.0, 12)]


def test_a_restart_into_the_same_folder_rewrites_the_later_frames_grids(tmp_path):
    """A restart from an earlier checkpoint into the run's own folder writes frames 2, 3, ...
    again, over those of the first timeline. Each rewritten frame's grid shows its new time,
    although the first rewrite of the XDMF read the old frames 3 and 4 from disk."""
    values = global_particles(3, 10)
    write_frames(tmp_path, values, 3, 1, times=(0.0, 1.0, 2.0, 3.0, 4.0))

    def resumed(comm):
        p = particle_set(3, share(values, comm.rank, comm.size, None))
        w = FrameWriter(tmp_path, comm, "", 3, [], {"restart_chain": []}, first_frame=2)
        w.write(p, 2.5, 25)
        w.write(p, 3.5, 35)

    run_ranks(1, resumed)
    assert check_xdmf(tmp_path / "particles.xdmf") == [(0.0, 10), (1.0, 10), (2.5, 10),
                                                       (3.5, 10), (4.0, 10)]

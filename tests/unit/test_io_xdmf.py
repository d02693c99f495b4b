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

"""``particles.xdmf``: the time series of frames as ParaView opens it (Xdmf3 reader).

An XDMF 3 file with one ``Collection`` grid (``CollectionType="Temporal"``) whose children are
``Uniform`` grids, one per frame file on disk: ``<Time Value>``, a ``Polyvertex`` topology of
``n_particles`` points with an explicit connectivity 0..n-1, the geometry ``/particles/x`` (``XYZ`` in 3D, ``XY`` in 2D, which
ParaView pads with z = 0) and node-centred attributes for every other dataset: ``id``, ``mass``,
``material`` and scalar extras as ``Scalar``, ``v`` as ``Vector``, ``F`` as ``Tensor`` (9
components) in 3D and ``Matrix`` (4 components, row-major F11 F12 F21 F22) in 2D. Paths to the
HDF5 files are relative, so the output folder can be moved. Rank 0 rewrites the file atomically
after every frame, from the frame files that exist, so it never names a missing file.

The connectivity: ParaView 5.11's Xdmf3 readers build no cells from a ``Polyvertex`` topology
given without one (n points, 0 cells: the default Surface and Points representations draw
nothing). With an integer ``DataItem`` 0..n-1 they build n vertex cells. The array is the same
for every frame of n particles, so it is written once per particle count, into
``polyvertex_<n>.h5:/connectivity`` (int32 below 2**31 particles), and shared by those frames:
4 B a particle per run instead of per frame.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from .shared import tmp_name, write_text_atomically

XDMF_NAME = "particles.xdmf"
FRAME_PATTERN = re.compile(r"^frame_(\d+)\.h5$")
CONNECTIVITY_DATASET = "connectivity"
# Rows of the connectivity written at once: bounds rank 0's memory for huge particle counts.
CONNECTIVITY_CHUNK = 1 << 24


def connectivity_name(n: int) -> str:
    """File holding the Polyvertex connectivity 0..n-1 shared by every frame of n particles."""
    return f"polyvertex_{int(n)}.h5"


def connectivity_dtype(n: int) -> np.dtype:
    return np.dtype(np.int32 if n < 2**31 else np.int64)


def write_connectivity(out_dir: Path, n: int) -> Path:
    """Write ``polyvertex_<n>.h5`` unless it exists (atomically: tmp + rename)."""
    import h5py

    path = Path(out_dir) / connectivity_name(n)
    if path.exists():
        return path
    tmp = tmp_name(path)
    with h5py.File(tmp, "w") as h5:
        dtype = connectivity_dtype(n)
        dset = h5.create_dataset(CONNECTIVITY_DATASET, (n,), dtype=dtype)
        for start in range(0, n, CONNECTIVITY_CHUNK):
            stop = min(n, start + CONNECTIVITY_CHUNK)
            dset[start:stop] = np.arange(start, stop, dtype=dtype)
    os.replace(tmp, path)
    return path


def number_type(dtype) -> tuple[str, int]:
    """XDMF ``NumberType`` and ``Precision`` of a numpy dtype."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return "Float", dtype.itemsize
    if dtype.kind == "i":
        return ("Char", 1) if dtype.itemsize == 1 else ("Int", dtype.itemsize)
    if dtype.kind in "ub":
        return ("UChar", 1) if dtype.itemsize == 1 else ("UInt", dtype.itemsize)
    raise ValueError(f"no XDMF number type for {dtype}")


def attribute_type(shape: tuple[int, ...], dim: int) -> str:
    trailing = tuple(shape[1:])
    if trailing == ():
        return "Scalar"
    if trailing == (dim,):
        return "Vector"
    if trailing == (3, 3):
        return "Tensor"
    return "Matrix"


def data_item(file: str, dataset: str, shape, dtype, indent: str,
              group: str = "/particles/") -> str:
    kind, precision = number_type(dtype)
    dims = " ".join(str(int(s)) for s in shape)
    return (f'{indent}<DataItem Dimensions="{dims}" NumberType="{kind}" '
            f'Precision="{precision}" Format="HDF">{escape(file)}:{group}{dataset}'
            f'</DataItem>\n')


def frame_grid(file: str, time: float, dim: int, n: int,
               shapes: dict[str, tuple[tuple[int, ...], str]]) -> str:
    """The ``Uniform`` grid of one frame; ``shapes`` maps dataset -> (shape, dtype str)."""
    name = Path(file).stem
    out = [f'      <Grid Name={quoteattr(name)} GridType="Uniform">\n',
           f'        <Time Value="{float(time)!r}"/>\n',
           f'        <Topology TopologyType="Polyvertex" NumberOfElements="{n}" '
           f'NodesPerElement="1">\n',
           data_item(connectivity_name(n), CONNECTIVITY_DATASET, (n,), connectivity_dtype(n),
                     "          ", group="/"),
           '        </Topology>\n',
           f'        <Geometry GeometryType="{"XYZ" if dim == 3 else "XY"}">\n',
           data_item(file, "x", *shapes["x"], "          "),
           '        </Geometry>\n']
    for dataset, (shape, dtype) in shapes.items():
        if dataset == "x":
            continue
        out.append(f'        <Attribute Name={quoteattr(dataset)} '
                   f'AttributeType="{attribute_type(shape, dim)}" Center="Node">\n')
        out.append(data_item(file, dataset, shape, dtype, "          "))
        out.append('        </Attribute>\n')
    out.append('      </Grid>\n')
    return "".join(out)


def xdmf_text(frames: list[tuple[str, float, int, int, dict]]) -> str:
    """The whole file for ``frames``: (relative file, time, dim, n, shapes) in order."""
    return xdmf_document("".join(frame_grid(*frame) for frame in frames))


def xdmf_document(body: str) -> str:
    """The XDMF file around ``body``, the frames' ``Uniform`` grids."""
    return ('<?xml version="1.0" ?>\n'
            '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n'
            '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">\n'
            '  <Domain>\n'
            '    <Grid Name="particles" GridType="Collection" CollectionType="Temporal">\n'
            f'{body}'
            '    </Grid>\n'
            '  </Domain>\n'
            '</Xdmf>\n')


def read_frame_header(path: Path) -> tuple[float, int, int, dict]:
    """(time, dim, n_particles, shapes) of an existing frame file."""
    import h5py

    with h5py.File(path, "r") as h5:
        shapes = {name: (tuple(d.shape), d.dtype.str) for name, d in h5["particles"].items()}
        return (float(h5.attrs["time"]), int(h5.attrs["dim"]), int(h5.attrs["n_particles"]),
                shapes)


class FrameCatalog:
    """Rank 0's record of the frames in ``out_dir``, from which ``particles.xdmf`` is written.

    Frames written by this run are recorded as they are written; frames already on disk (a
    restart into the same folder) are read once from their headers. Unreadable files are left
    out of the XDMF rather than breaking it."""

    def __init__(self, out_dir: Path):
        self.out_dir = Path(out_dir)
        self.entries: dict[int, tuple[float, int, int, dict]] = {}
        # Each frame's grid text, rendered once: the file is rewritten after every frame, and
        # re-rendering every earlier frame made a long run's output quadratic in its frames.
        self._grids: dict[tuple[int, str], str] = {}

    def add(self, index: int, time: float, dim: int, n: int, shapes: dict) -> None:
        self.entries[index] = (time, dim, n, shapes)
        self._grids = {k: v for k, v in self._grids.items() if k[0] != index}

    def on_disk(self) -> dict[int, Path]:
        found = {}
        for path in self.out_dir.iterdir():
            match = FRAME_PATTERN.match(path.name)
            if match:
                found[int(match.group(1))] = path
        return found

    def write(self) -> Path:
        """Rewrite ``particles.xdmf`` (and any missing connectivity file) from the frames on
        disk."""
        files = self.on_disk()
        self.entries = {i: e for i, e in self.entries.items() if i in files}
        for index, path in files.items():
            if index not in self.entries:
                try:
                    self.entries[index] = read_frame_header(path)
                except (OSError, KeyError):
                    continue
        body = []
        for n in {entry[2] for entry in self.entries.values()}:
            write_connectivity(self.out_dir, n)
        for i in sorted(self.entries):
            key = (i, files[i].name)
            if key not in self._grids:
                self._grids[key] = frame_grid(files[i].name, *self.entries[i])
            body.append(self._grids[key])
        target = self.out_dir / XDMF_NAME
        write_text_atomically(target, xdmf_document("".join(body)))
        return target

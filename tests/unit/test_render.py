"""hpcmpm render and hpcmpm plot: pictures of known frames land where the particles are, the
movie has every rendered frame, the diagnostics CSV holds the frames' numbers exactly, and bad
requests are one-line errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_io_threadranks import run_ranks

from hpcmpm.io.frames import FrameWriter
from hpcmpm.scene import parse_scene
from hpcmpm.state import TENSOR, FieldSpec, ParticleSet
from hpcmpm.viz.diagnostics import read_csv
from hpcmpm.viz.movie import find_ffmpeg, movie_frame_count
from hpcmpm.viz.render import render_run
from hpcmpm.viz.series import RenderError, list_frames, select_frames


class OneRank:
    """The Communicator verbs for a single process (no MPI needed)."""

    rank, size = 0, 1

    def bcast(self, obj, root=0):
        return obj

    def min(self, x):
        return x

    def max(self, x):
        return x

    def allgather(self, obj):
        return [obj]

    def barrier(self):
        pass


SCENE_2D = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [2.0, 1.0] }
dx = 0.04
particles_per_cell = 2
end_time = 1.0
[output]
every = 0.1
[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1000.0
E = 1000.0
nu = 0.3
[[bodies]]
name = "b"
material = "rubber"
shape = "box"
lower = [0.2, 0.5]
upper = [0.6, 0.9]
"""
SCENE_3D = SCENE_2D.replace("dim = 2", "dim = 3").replace(
    "{ lower = [0.0, 0.0], upper = [2.0, 1.0] }", "{ lower = [0.0, 0.0, 0.0], upper = [1.0, 1.0, 1.0] }"
).replace("lower = [0.2, 0.5]", "lower = [0.1, 0.5, 0.2]").replace(
    "upper = [0.6, 0.9]", "upper = [0.4, 0.8, 0.5]").replace("dx = 0.04", "dx = 0.05")
SPACING = {2: 0.02, 3: 0.025}  # dx / particles_per_cell


def lattice(lower, upper, spacing) -> np.ndarray:
    axes = [np.arange(lo + spacing / 2, hi, spacing) for lo, hi in zip(lower, upper)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lower))


def write_known_run(out: Path, scene_text: str, x: np.ndarray, times=(0.0,), speeds=None):
    """Frames of particles at ``x`` with velocity (s, 0, ...) for s in ``speeds``."""
    scene = parse_scene(scene_text)
    dim = scene.dim
    speeds = speeds or [1.0] * len(times)

    def body(comm):
        writer = FrameWriter(out, comm, scene.text, dim, [],
                             {"restart_chain": [f"/somewhere/known_{dim}d.toml"]})
        for step, (t, s) in enumerate(zip(times, speeds)):
            p = ParticleSet(dim, {"F": FieldSpec(TENSOR, "f8", "identity")})
            n = len(x)
            v = np.zeros((n, dim))
            v[:, 0] = s
            p.append({"id": np.arange(n, dtype=np.int64), "x": x, "v": v,
                      "mass": np.ones(n), "group": np.zeros(n, np.int32),
                      "F": np.tile(np.eye(dim), (n, 1, 1))})
            writer.write(p, t, step, {"kinetic_energy": 0.5 * n * s * s,
                                      "elastic_energy": 0.0, "total_energy": 0.5 * n * s * s})

    run_ranks(1, body)
    return out


def coloured(image: np.ndarray) -> np.ndarray:
    """Pixels with colour in them: particles are drawn in viridis colours (no grey in it),
    the background is white and box edges, colliders and text are grey."""
    spread = image.max(axis=2).astype(int) - image.min(axis=2).astype(int)
    return spread > 10


def read_png(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def box_in_pixels(image: np.ndarray) -> tuple[int, int, int, int]:
    """(first column, last column, first row, last row) of the domain box: its top and bottom
    edges are the only dark lines across a third of the picture; its columns are the longest
    dark run along the top edge (the colour bar's dark outline lies beside it)."""
    dark = image.max(axis=2) < 60
    rows = np.flatnonzero(dark.sum(axis=1) > dark.shape[1] / 3)
    top = np.concatenate(([0], dark[rows[0]].astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(top))
    starts, stops = edges[0::2], edges[1::2]
    longest = np.argmax(stops - starts)
    return starts[longest], stops[longest] - 1, rows[0], rows[-1]


def test_2d_picture_has_its_size_and_the_particles_where_they_are(tmp_path):
    x = lattice((0.2, 0.5), (0.6, 0.9), SPACING[2])
    run = write_known_run(tmp_path / "run", SCENE_2D, x)
    result = render_run(run, size=(400, 240), comm=OneRank())
    image = read_png(result.pngs[0])
    assert image.shape == (240, 400, 3)
    assert image.astype(float).var() > 100.0  # not blank: white + particles + box + text
    # The domain box [0, 2] x [0, 1] as drawn gives the data -> pixel map (independent of the
    # renderer's internals); true aspect ratio: 2 : 1 within the 1-2 px width of its lines.
    c0, c1, r0, r1 = box_in_pixels(image)
    assert abs((c1 - c0) / (r1 - r0) - 2.0) < 0.05
    sx, sy = (c1 - c0) / 2.0, (r1 - r0) / 1.0
    # Particle disks (diameter = spacing) fill [0.2, 0.6] x [0.5, 0.9]; y grows upwards.
    want = (c0 + 0.2 * sx, c0 + 0.6 * sx, r1 - 0.9 * sy, r1 - 0.5 * sy)
    rows, cols = np.nonzero(coloured(image[:, : c1 + 2]))  # left of the colour bar
    got = (cols.min(), cols.max(), rows.min(), rows.max())
    # 2 px: the box line width and anti-aliased disk edges.
    assert np.allclose(got, want, atol=2.0), (got, want)


def test_3d_picture_has_its_size_and_the_particles_where_they_are(tmp_path):
    x = lattice((0.1, 0.5, 0.2), (0.4, 0.8, 0.5), SPACING[3])
    run = write_known_run(tmp_path / "run", SCENE_3D, x)
    camera = "eye=0.5,-2.5,0.5;target=0.5,0.5,0.5;up=0,0,1;fov=30"
    result = render_run(run, size=(360, 300), camera=camera, comm=OneRank())
    image = read_png(result.pngs[0])
    assert image.shape == (300, 360, 3)
    assert image.astype(float).var() > 100.0
    # The camera looks along +y from y = -2.5 with z up: a point projects to
    # column = w/2 + f (x - 0.5) / (y + 2.5), row = h/2 - f (z - 0.5) / (y + 2.5), f the
    # focal length in pixels, (h/2) / tan(fov/2), within the view's rectangle of the figure.
    from hpcmpm.viz.layout import Canvas, colour_scale
    from hpcmpm.viz.fields import FieldChoice

    left, bottom, w, h = Canvas((360, 300), colour_scale(FieldChoice("speed"), 0, 1),
                                "").view_px
    top = 300 - bottom - h
    f = 0.5 * h / math.tan(math.radians(15))
    r = SPACING[3] / 2
    lo, hi = x.min(axis=0) - r, x.max(axis=0) + r
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                        for c in (lo[2], hi[2])])
    depth = corners[:, 1] + 2.5
    cols = left + w / 2 + f * (corners[:, 0] - 0.5) / depth
    rows = top + h / 2 - f * (corners[:, 2] - 0.5) / depth
    pr, pc = np.nonzero(coloured(image[top: top + h, left: left + w]))
    pr, pc = pr + top, pc + left
    # Every coloured pixel inside the projected bounding box (1 px for anti-aliasing), and the
    # particles cover it: their pixels reach within 3 px of its near face (y = lo) edges,
    # which the spheres of the front layer touch.
    assert pc.min() >= cols.min() - 1 and pc.max() <= cols.max() + 1
    assert pr.min() >= rows.min() - 1 and pr.max() <= rows.max() + 1
    front = depth == depth.min()
    assert abs(pc.min() - cols[front].min()) <= 3 and abs(pc.max() - cols[front].max()) <= 3
    assert abs(pr.min() - rows[front].min()) <= 3 and abs(pr.max() - rows[front].max()) <= 3


@pytest.mark.needs_tool
@pytest.mark.parametrize("fmt", ["gif", "mp4"])
def test_movie_has_every_rendered_frame(tmp_path, fmt):
    if fmt == "mp4" and find_ffmpeg() is None:
        pytest.skip("no ffmpeg (pip install imageio-ffmpeg): MP4 not available, GIF is used")
    if fmt == "mp4":
        pytest.importorskip("imageio_ffmpeg", reason="counting MP4 frames needs imageio-ffmpeg")
    x = lattice((0.2, 0.5), (0.6, 0.9), SPACING[2])
    run = write_known_run(tmp_path / "run", SCENE_2D, x, times=(0.0, 0.1, 0.2, 0.3, 0.4),
                          speeds=[0.0, 1.0, 2.0, 3.0, 4.0])
    result = render_run(run, frames="1:", size=(240, 160), movie=fmt, comm=OneRank())
    assert [p.name for p in result.pngs] == [f"render_00000{i}.png" for i in (1, 2, 3, 4)]
    assert result.movie.suffix == f".{fmt}"
    assert movie_frame_count(result.movie) == 4
    # One colour scale over the rendered frames (speeds 1, 2, 3, 4 -> 0, 1/3, 2/3, 1 of
    # viridis, whose green channel grows from 1 to 231), not each frame normalised alone
    # (which would paint every frame in the same mid colour).
    greens = []
    for path in result.pngs:
        image = read_png(path)
        c0, c1, r0, r1 = box_in_pixels(image)
        inside = image[r0:r1, c0:c1]  # the domain, without the colour bar
        greens.append(np.median(inside[coloured(inside)][:, 1]))
    assert greens == sorted(greens) and greens[-1] - greens[0] > 150, greens


def test_frames_being_written_and_missing_files(tmp_path):
    x = lattice((0.2, 0.5), (0.6, 0.9), 0.05)
    run = write_known_run(tmp_path / "run", SCENE_2D, x, times=(0.0, 0.1, 0.2))
    (run / "frame_000001.h5").unlink()  # the XDMF still names it
    assert [f.index for f in list_frames(run)] == [0, 2]
    result = render_run(run, size=(160, 120), movie="none", comm=OneRank())
    assert [p.name for p in result.pngs] == ["render_000000.png", "render_000002.png"]
    assert result.movie is None


def test_frames_range_parsing():
    frames = list(range(10))
    assert select_frames(frames, None) == frames
    assert select_frames(frames, "-1") == [9]
    assert select_frames(frames, "::4") == [0, 4, 8]
    assert select_frames(frames, "2:5") == [2, 3, 4]
    assert select_frames(frames, "-3:") == [7, 8, 9]
    for spec, message in [("a:b", "expected integers"), ("1:2:3:4", "expected A:B:K"),
                          ("::0", "must not be 0"), ("12", "no such frame, the run has 10"),
                          ("5:5", "selects none of the run's 10 frames")]:
        with pytest.raises(RenderError, match=message):
            select_frames(frames, spec)


def hpcmpm(capsys, *args) -> tuple[int, str]:
    """The console script's entry point in this process: (exit code, stderr)."""
    from hpcmpm.cli import main

    capsys.readouterr()
    code = main(list(args))
    return code, capsys.readouterr().err


def test_cli_errors_are_one_line(tmp_path, capsys):
    x = lattice((0.2, 0.5), (0.6, 0.9), 0.05)
    run = write_known_run(tmp_path / "run", SCENE_2D, x)
    cases = [(["--field", "damage"], "no field 'damage' in the frames; fields: F, J, id, "
                                     "mass, material, speed, v"),
             (["--field", "v:w"], "--field v:w: no component 'w' in v of shape (2,); use x, y, "
                                  "0..1 or norm"),
             (["--frames", "1:x"], "--frames '1:x': expected integers in A:B:K"),
             (["--size", "12by3"], "--size '12by3': expected WxH in pixels, e.g. 960x720"),
             (["--camera", "eye=1,2"], "--camera applies to 3D runs only")]
    for args, message in cases:
        code, err = hpcmpm(capsys, "render", str(run), "--quiet", *args)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err
        assert lines[0].startswith(f"hpcmpm: error: {message}"), lines[0]
    for verb in ("render", "plot"):
        code, err = hpcmpm(capsys, verb, str(tmp_path / "nothing"))
        assert code == 2 and "no such run folder" in err, (verb, err)
        assert not (tmp_path / "nothing").exists(), verb    # a typo makes no folder


def test_frames_from_the_end_on_the_command_line(tmp_path, capsys):
    """`--frames -2:` (a value that starts with "-" and is no number) reaches the renderer
    instead of argparse's "expected one argument"."""
    x = lattice((0.2, 0.5), (0.6, 0.9), 0.05)
    run = write_known_run(tmp_path / "run", SCENE_2D, x, times=(0.0, 0.1, 0.2))
    code, err = hpcmpm(capsys, "render", str(run), "--quiet", "--movie", "none",
                       "--size", "120x90", "--frames", "-2:")
    assert code == 0, err
    assert sorted(p.name for p in (run / "render").glob("render_*.png")) == \
        ["render_000001.png", "render_000002.png"]


def test_plot_reproduces_the_energy_series(tmp_path, capsys):
    run = tmp_path / "disks"
    code, err = hpcmpm(capsys, "run", "inputs/disks_2d.toml", "--out", str(run), "--quiet",
                       "--end-time", "0.3", "--set", "simulation.dx=0.05")
    assert code == 0, err
    code, err = hpcmpm(capsys, "plot", str(run))
    assert code == 0, err
    table = read_csv(run / "diagnostics.csv")
    assert (run / "diagnostics.png").stat().st_size > 5000
    frames = sorted(run.glob("frame_*.h5"))
    assert len(table["time"]) == len(frames) == 4
    for i, path in enumerate(frames):
        with h5py.File(path) as h5:
            # Exactly: the CSV is written with repr, which round-trips float64.
            for key in ("time", "kinetic_energy", "elastic_energy", "total_energy", "mass"):
                assert table[key][i] == h5.attrs[key], key
            # Vectors are JSON text in the frame (floats by repr, so exact too).
            momentum = json.loads(h5.attrs["momentum"])
            for k, axis in enumerate("xyz"):
                assert table[f"momentum_{axis}"][i] == momentum[k]


def test_field_values_and_components():
    from hpcmpm.viz.fields import available_fields, field_values, parse_field

    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.1 * rng.standard_normal((5, 3, 3))
    tau = rng.standard_normal((5, 3, 3))
    v = rng.standard_normal((5, 3))
    data = {"v": v, "F": F, "tau": tau, "material": np.arange(5, dtype=np.int32)}
    shapes = {k: a.shape for k, a in data.items()}
    assert available_fields(shapes) == ["F", "J", "material", "pressure", "speed", "tau", "v"]

    def values(spec):
        return field_values(parse_field(spec), data, 3)

    # Each against its definition written out here.
    np.testing.assert_allclose(values(None), np.sqrt((v ** 2).sum(axis=1)), rtol=1e-15)
    np.testing.assert_array_equal(values("v:y"), v[:, 1])
    np.testing.assert_array_equal(values("v:2"), v[:, 2])
    np.testing.assert_array_equal(values("F:xz"), F[:, 0, 2])
    np.testing.assert_array_equal(values("F:2,1"), F[:, 2, 1])
    np.testing.assert_array_equal(values("F:5"), F[:, 1, 2])  # flat row-major index
    np.testing.assert_allclose(values("F:trace"), F[:, 0, 0] + F[:, 1, 1] + F[:, 2, 2])
    J = np.array([np.linalg.det(f) for f in F])
    np.testing.assert_allclose(values("J"), J, rtol=1e-13)
    np.testing.assert_allclose(values("F:det"), J, rtol=1e-13)
    # pressure = -tr(sigma) / d with sigma = tau / J
    np.testing.assert_allclose(values("pressure"),
                               -(tau[:, 0, 0] + tau[:, 1, 1] + tau[:, 2, 2]) / (3 * J),
                               rtol=1e-13)
    np.testing.assert_array_equal(values("material"), np.arange(5.0))
    for spec, message in [("material:x", "is a scalar"), ("F:xw", "no component 'xw'"),
                          ("v:3", "no component '3'")]:
        with pytest.raises(RenderError, match=message):
            values(spec)

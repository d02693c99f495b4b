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


@pytest.mark.parametrize("dim,size", [(2, (96, 64)), (3, (96, 64)), (3, (8192, 64)),
                                      (2, (96, 8192))])
def test_the_extreme_sizes_render(tmp_path, dim, size):
    """The smallest accepted picture (series.MIN_SIZE) and the widest and tallest at its
    other side have a view to draw in: below 60 x 26, and at 8192 x 64 (a margin grown with
    the width), the view had no pixels and matplotlib raised."""
    from hpcmpm.viz.layout import Canvas, colour_scale
    from hpcmpm.viz.fields import FieldChoice

    x = lattice((0.2, 0.5, 0.2)[:dim], (0.6, 0.9, 0.5)[:dim], SPACING[dim])
    run = write_known_run(tmp_path / "run", SCENE_2D if dim == 2 else SCENE_3D, x)
    result = render_run(run, size=size, movie="none", comm=OneRank())
    assert read_png(result.pngs[0]).shape == (size[1], size[0], 3)
    view = Canvas(size, colour_scale(FieldChoice("speed"), 0, 1), "").view_px
    assert view[2] >= 40 and view[3] >= 40, view


def test_size_fps_and_camera_out_of_range_are_one_line_errors():
    from hpcmpm.viz.render3d import Camera, parse_camera
    from hpcmpm.viz.series import check_fps, parse_size

    assert parse_size("96x64") == (96, 64)
    for spec in ("95x64", "96x63", "8193x100", "16x16"):
        with pytest.raises(RenderError, match="width must be 96..8192 and height 64..8192"):
            parse_size(spec)
    check_fps(0.01)
    check_fps(1000.0)
    for fps in (0.0, -1.0, math.nan, math.inf, 1e-320, 1001.0):
        with pytest.raises(RenderError, match="must be 0.01..1000 frames per second"):
            check_fps(fps)
    default = Camera(np.array([0.0, -3.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    # A direction is a direction at any magnitude (|up|^2 underflows here).
    tiny = parse_camera("up=0,1e-200,1e-200", default).basis()
    unit = parse_camera("up=0,1,1", default).basis()
    np.testing.assert_allclose(tiny, unit, rtol=0, atol=1e-15)
    for spec, message in [("eye=1e308,0,0;target=-1e308,0,0", "target - eye overflows"),
                          ("up=0,0,0", "up is the zero vector"),
                          ("eye=nan,0,0", "eye needs three numbers"),
                          ("up=0,1,0;eye=0,-3,0", "parallel to the viewing direction")]:
        with pytest.raises(RenderError, match=message):
            parse_camera(spec, default)


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
        frame = sorted(run.glob("frame_*.h5"))[0]
        code, err = hpcmpm(capsys, verb, str(frame))
        assert code == 2 and f"{frame}: a file, not a run folder; give the folder that " \
            f"holds the run's frames ({run})" in err, (verb, err)


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


def test_3d_nearer_sphere_hides_the_farther_one():
    """Depth test: a red sphere in front of a larger blue one, on the camera's axis, is what
    the centre of the picture shows (not whichever sphere was drawn last)."""
    from hpcmpm.viz.fields import FieldChoice
    from hpcmpm.viz.layout import colour_scale
    from hpcmpm.viz.render3d import Camera, Renderer3D
    from hpcmpm.viz.series import RunGeometry

    geometry = RunGeometry("t", 3, np.zeros(3), np.ones(3), 0.1)
    camera = Camera(np.array([0.0, -5.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    renderer = Renderer3D(geometry, colour_scale(FieldChoice("speed"), 0, 1), (200, 160),
                          camera)
    # Near (y = -1, depth 4) red; far (y = +1, depth 6), three times wider, blue. Far first.
    x = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    rgba = renderer.raster(x, np.array([0.6, 0.2]), np.array([[0.0, 0.0, 1.0],
                                                               [1.0, 0.0, 0.0]]))
    h, w = rgba.shape[:2]
    centre = rgba[h // 2 - 2: h // 2 + 2, w // 2 - 2: w // 2 + 2]
    assert np.all(centre[..., 3] == 1.0)
    assert np.all(centre[..., 0] > 0.3) and np.all(centre[..., 2] < 0.3), centre[..., :3]
    # Beyond the red sphere's outline (0.2 at depth 4) but inside the blue one's: blue.
    f = 0.5 * h / math.tan(math.radians(15))  # focal length in pixels, fov 30 degrees
    col = int(round(w / 2 + f * 0.35 / 6))
    assert rgba[h // 2, col, 2] > 0.3 and rgba[h // 2, col, 0] < 0.3, rgba[h // 2, col]


def test_default_camera_sees_the_whole_domain_from_above(tmp_path):
    """The default 3D camera looks at the domain's centre from above (along the up axis, the
    one opposite to gravity) and far enough that the domain's bounding sphere fits its
    vertical field of view; a scene with gravity along -y has y up."""
    from hpcmpm.viz.render3d import default_camera
    from hpcmpm.viz.series import run_geometry

    lower, upper = np.array([0.0, -1.0, 2.0]), np.array([2.0, 0.5, 3.0])
    centre, radius = (lower + upper) / 2, np.linalg.norm(upper - lower) / 2
    for up_axis in (0, 1, 2):
        camera = default_camera(lower, upper, up_axis, fov=30.0)
        np.testing.assert_allclose(camera.target, centre)
        np.testing.assert_array_equal(camera.up, np.eye(3)[up_axis])
        offset = camera.eye - centre
        assert offset[up_axis] > 0.2 * np.linalg.norm(offset), (up_axis, offset)  # above
        # Half the angle the bounding sphere subtends at the eye is within half the fov.
        assert math.degrees(math.asin(radius / np.linalg.norm(offset))) <= 15.0, up_axis

    x = lattice((0.1, 0.5, 0.2), (0.4, 0.8, 0.5), 0.05)
    scene = SCENE_3D.replace("end_time = 1.0", "end_time = 1.0\ngravity = [0.0, -9.81, 0.0]")
    run = write_known_run(tmp_path / "run", scene, x)
    assert run_geometry(list_frames(run)[0], run, x).up_axis == 1


def test_3d_frames_without_a_scene_render_with_the_default_camera(tmp_path):
    """Frames whose scene text is not a valid scene (the geometry falls back to the particles'
    bounding box, up_axis -1 = the last axis) still render in 3D with the default camera."""
    x = lattice((0.1, 0.5, 0.2), (0.4, 0.8, 0.5), 0.05)
    run = write_known_run(tmp_path / "run", SCENE_3D, x)
    with h5py.File(run / "frame_000000.h5", "r+") as h5:
        h5.attrs["scene"] = ""
    result = render_run(run, size=(200, 150), comm=OneRank())
    image = read_png(result.pngs[0])
    assert image.shape == (150, 200, 3) and coloured(image).sum() > 200


COLLIDERS_2D = """
[[colliders]]
name = "floor"
shape = "half_space"
point = [1.0, 0.3]
normal = [1.0, 1.0]
[[colliders]]
name = "paddle"
shape = "box"
center = [1.4, 0.5]
half_extents = [0.3, 0.1]
rotation = 0.5
angular_velocity = 1.0
"""


def test_2d_colliders_are_drawn_where_they_are():
    """The half-space is drawn on its obstacle side ((x - point) . normal < 0), and a box
    turned by angle0 + omega t has its corners at centre + R(angle) (+-hx, +-hy)."""
    from matplotlib.path import Path as MplPath

    from hpcmpm.boundaries.colliders import Collider
    from hpcmpm.viz.render2d import collider_patches
    from hpcmpm.viz.series import RunGeometry

    scene = parse_scene(SCENE_2D + COLLIDERS_2D)
    geometry = RunGeometry("t", 2, np.array([0.0, 0.0]), np.array([2.0, 1.0]), 0.02,
                           colliders=[Collider(c, 2) for c in scene.colliders])
    half_space, box = collider_patches(geometry, 0.3, 2.0)
    n = np.array([1.0, 1.0]) / math.sqrt(2)
    outline = MplPath(half_space.get_xy())
    point = np.array([1.0, 0.3])
    assert outline.contains_point(point - 0.2 * n)       # inside the obstacle
    assert not outline.contains_point(point + 0.2 * n)   # the material's side
    angle = 0.5 + 1.0 * 0.3
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    want = {tuple(np.round([1.4, 0.5] + R @ [sx * 0.3, sy * 0.1], 9))
            for sx in (-1, 1) for sy in (-1, 1)}
    got = {tuple(np.round(p, 9)) for p in box.get_xy()}
    assert got == want, (got, want)


def test_colour_scales_of_materials_uniform_fields_and_nan():
    """One distinct colour per material index up to the largest (names or not); a uniform
    field gets a band around its value (its colour mid-scale); NaN does not spoil the range."""
    from hpcmpm.viz.fields import FieldChoice
    from hpcmpm.viz.layout import colour_scale
    from hpcmpm.viz.series import finite_range

    scale = colour_scale(FieldChoice("material"), 0.0, 3.0, [])
    colours = [tuple(c) for c in scale.rgba(np.arange(4.0))]
    assert len(set(colours)) == 4 and scale.ticklabels == ["0", "1", "2", "3"]
    scale = colour_scale(FieldChoice("material"), 0.0, 1.0, ["steel", "rubber", "snow"])
    assert scale.ticklabels == ["steel", "rubber", "snow"]

    uniform = colour_scale(FieldChoice("speed"), 2.0, 2.0)
    assert uniform.norm.vmin < 2.0 < uniform.norm.vmax
    assert uniform.norm(2.0) == pytest.approx(0.5)
    # A spread of round-off (disks in free flight: speed 0.1414213562 +- 1e-15) is uniform
    # too: one colour mid-scale, not the whole map over 1e-15.
    speed = math.sqrt(0.02) + np.array([-1.4e-15, 0.0, 1.5e-15])
    flat = colour_scale(FieldChoice("speed"), speed.min(), speed.max())
    assert np.abs(flat.norm(speed) - 0.5).max() < 1e-12
    assert flat.norm.vmax - flat.norm.vmin == pytest.approx(0.1 * math.sqrt(0.02))
    # Zero everywhere (no bond broken yet): [0, 1], no negative damage on the bar.
    zero = colour_scale(FieldChoice("damage"), 0.0, 0.0)
    assert (zero.norm.vmin, zero.norm.vmax) == (0.0, 1.0)
    # A small physical spread keeps the full map: J within 1e-9 of 1 (a nearly
    # incompressible fluid) is 1e-9 relative, above round-off.
    J = 1.0 + np.array([-1e-9, 1e-9])
    assert list(colour_scale(FieldChoice("J"), J.min(), J.max()).norm(J)) == [0.0, 1.0]

    assert finite_range(np.array([np.nan, 5.0, -np.inf, 2.0, np.inf])) == (2.0, 5.0)
    assert finite_range(np.array([np.nan, np.nan])) == (math.inf, -math.inf)


def test_frames_from_the_very_first_by_a_negative_index():
    frames = list(range(10))
    assert select_frames(frames, "-10") == [0]
    assert select_frames(frames, "9") == [9]
    with pytest.raises(RenderError, match="no such frame"):
        select_frames(frames, "-11")


def test_pressure_of_a_frame_that_carries_J_without_F():
    """A fluid (deformation = "J") writes J and tau but no F: pressure is read from them."""
    from hpcmpm.viz.fields import FieldChoice, datasets_needed, field_values

    rng = np.random.default_rng(7)
    tau, J = rng.standard_normal((4, 2, 2)), 1.0 + 0.1 * rng.random(4)
    needed = datasets_needed(FieldChoice("pressure"), {"tau": (4, 2, 2), "J": (4,)})
    assert sorted(needed) == ["J", "tau"]
    data = {"tau": tau, "J": J}
    np.testing.assert_allclose(field_values(FieldChoice("pressure"), data, 2),
                               -(tau[:, 0, 0] + tau[:, 1, 1]) / (2 * J), rtol=1e-14)


def _speeds_run(tmp_path, speeds):
    x = lattice((0.2, 0.5), (0.6, 0.9), SPACING[2])
    times = tuple(0.1 * i for i in range(len(speeds)))
    return write_known_run(tmp_path / "run", SCENE_2D, x, times=times, speeds=list(speeds))


def _mean_abs(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(float) - b.astype(float)).mean())


def test_gif_plays_the_frames_in_order_at_the_frame_rate(tmp_path):
    """Frame i of the GIF is PNG i (the nearest of the PNGs: GIF quantises colours), each
    shown 1000 / fps ms; a single rendered frame makes no movie."""
    from PIL import Image

    run = _speeds_run(tmp_path, [0.0, 2.0, 4.0])
    result = render_run(run, size=(160, 120), fps=5.0, movie="gif", comm=OneRank())
    pngs = [read_png(p) for p in result.pngs]
    with Image.open(result.movie) as gif:
        assert gif.n_frames == 3
        for i in range(3):
            gif.seek(i)
            assert gif.info["duration"] == 200, gif.info
            frame = np.asarray(gif.convert("RGB"))
            distances = [_mean_abs(frame, png) for png in pngs]
            assert int(np.argmin(distances)) == i, (i, distances)
    one = render_run(run, frames="-1", out=tmp_path / "one", size=(160, 120), movie="gif",
                     comm=OneRank())
    assert one.movie is None and not list((tmp_path / "one").glob("render.*"))


@pytest.mark.needs_tool
def test_mp4_lasts_frames_over_fps(tmp_path):
    if find_ffmpeg() is None:
        pytest.skip("no ffmpeg (pip install imageio-ffmpeg): MP4 not available, GIF is used")
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg",
                                         reason="reading MP4 frames needs imageio-ffmpeg")
    run = _speeds_run(tmp_path, [0.0, 1.0, 2.0, 3.0])
    result = render_run(run, size=(160, 120), fps=5.0, movie="mp4", comm=OneRank())
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(result.movie))
    assert frames == 4 and seconds == pytest.approx(4 / 5.0, abs=0.05), (frames, seconds)
    # And in order: the decoded frames' nearest PNGs are 0, 1, 2, 3 (the codec is lossy).
    reader = imageio_ffmpeg.read_frames(str(result.movie))
    meta = next(reader)
    w, h = meta["size"]
    pngs = [read_png(p) for p in result.pngs]
    for i, raw in enumerate(reader):
        frame = np.frombuffer(raw, np.uint8).reshape(h, w, 3)[:120, :160]
        assert int(np.argmin([_mean_abs(frame, png) for png in pngs])) == i


def test_ranks_render_only_the_frames_dealt_to_them(tmp_path, monkeypatch):
    """Rank 1 of 2 draws frames 1 and 3 of 0..3 (round-robin), not the others' frames."""
    import hpcmpm.viz.render as render_module

    class SecondOfTwo(OneRank):
        rank, size = 1, 2

    # The plan is rank 0's work: here this rank makes it itself.
    monkeypatch.setattr(render_module, "_on_root", lambda comm, work: work())
    run = _speeds_run(tmp_path, [0.0, 1.0, 2.0, 3.0])
    out = tmp_path / "pictures"
    out.mkdir()
    render_run(run, out=out, size=(120, 90), movie="none", comm=SecondOfTwo())
    assert sorted(p.name for p in out.glob("render_*.png")) == \
        ["render_000001.png", "render_000003.png"]


def test_plot_panels_draw_each_diagnostic_against_time():
    """Every curve of the diagnostics figure is (time, that column), grouped into panels."""
    from hpcmpm.viz.diagnostics import diagnostic_panels

    rows = [{"frame": i, "time": 0.25 * i, "step": 7 * i, "mass": 2.0, "momentum_x": 1.0 + i,
             "momentum_y": -i, "kinetic_energy": 3.0 * i, "total_energy": 3.0 * i + 1,
             "cg_iterations": 10 + i} for i in range(4)]
    columns = list(rows[0])
    panels = diagnostic_panels(columns, rows)
    curves = {c.label: c for p in panels for c in p.curves}
    assert set(curves) == {"mass", "momentum_x", "momentum_y", "kinetic_energy",
                           "total_energy", "cg_iterations"}
    for name, curve in curves.items():
        assert list(curve.x) == [0.0, 0.25, 0.5, 0.75], name
        assert list(curve.y) == [r[name] for r in rows], name
    assert [sorted(c.label for c in p.curves) for p in panels] == [
        ["mass"], ["momentum_x", "momentum_y"], ["kinetic_energy", "total_energy"],
        ["cg_iterations"]]


def test_curve_against_reference_returns_the_plotted_difference(tmp_path):
    """What the verification tests assert on: y - y_ref at x, divided by ``relative_to``,
    for a reference function and for a tabulated one (linear interpolation)."""
    from hpcmpm.viz.plots import curve_against_reference

    x = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    y = np.array([1.0, 2.0, 2.5, 4.0, 3.0])
    diff = curve_against_reference(tmp_path / "f.png", x, y, lambda s: 2.0 * s,
                                   relative_to=4.0)
    np.testing.assert_allclose(diff, [0.25, 0.25, 0.125, 0.25, -0.25], rtol=1e-15)
    # Tabulated at 0, 1, 3 with values 0, 10, 30: y_ref(x) = 10 x.
    diff = curve_against_reference(tmp_path / "g.png", x, y,
                                   ([0.0, 1.0, 3.0], [0.0, 10.0, 30.0]))
    np.testing.assert_allclose(diff, y - 10.0 * x, rtol=1e-15)
    assert (tmp_path / "f.png").stat().st_size > 5000


def test_pictures_of_frames_the_run_no_longer_has_are_removed(tmp_path):
    """Rendering a run whose folder holds PNGs of frames it does not have (from a longer run
    it replaced) deletes those, keeps the pictures of its own frames, rendered now or not,
    and leaves other files alone."""
    x = lattice((0.2, 0.5), (0.6, 0.9), 0.05)
    run = write_known_run(tmp_path / "run", SCENE_2D, x, times=(0.0, 0.1, 0.2))
    pictures = run / "render"
    pictures.mkdir()
    for name in ("render_000001.png", "render_000007.png", "render_000033.png", "notes.png",
                 "render_1.png"):
        (pictures / name).write_bytes(b"old")
    result = render_run(run, frames="-1:", size=(160, 120), movie="none", comm=OneRank())
    assert [p.name for p in result.pngs] == ["render_000002.png"]
    assert sorted(p.name for p in pictures.iterdir()) == [
        "notes.png", "render_000001.png", "render_000002.png", "render_1.png"]
    assert (pictures / "render_000001.png").read_bytes() == b"old"   # frame 1 exists

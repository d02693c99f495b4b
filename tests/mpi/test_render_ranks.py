"""``mpiexec -n 2 hpcmpm render`` deals the frames to the ranks and gives the same pictures as
one rank: the PNGs are pixel for pixel equal (one colour scale reduced over the ranks), and
rank 0's movie holds every frame."""

from pathlib import Path

import numpy as np

from hpcmpm.cli import main
from hpcmpm.viz.movie import movie_frame_count
from launch import mpi_hpcmpm


def pixels(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def test_two_ranks_render_what_one_rank_renders(tmp_path):
    run = tmp_path / "jelly"
    # A coarse jelly cube (343 particles), frames at t = 0, 0.04, 0.08, 0.12: every rank
    # gets two frames and the speed range differs between them.
    assert main(["run", "inputs/jelly_cube_3d.toml", "--out", str(run), "--quiet",
                 "--end-time", "0.12", "--set", "simulation.dx=0.1"]) == 0
    args = ["--size", "200x150", "--movie", "gif", "--quiet"]
    assert main(["render", str(run), "--out", str(tmp_path / "one"), *args]) == 0
    proc = mpi_hpcmpm(2, "render", str(run), "--out", str(tmp_path / "two"), *args, timeout=240)
    assert "2 rank(s)" in proc.stdout and "movie: " in proc.stdout
    one = sorted((tmp_path / "one").glob("render_*.png"))
    two = sorted((tmp_path / "two").glob("render_*.png"))
    assert [p.name for p in one] == [p.name for p in two] == \
        [f"render_{i:06d}.png" for i in range(4)]
    for a, b in zip(one, two):
        assert np.array_equal(pixels(a), pixels(b)), a.name
    assert movie_frame_count(tmp_path / "two" / "render.gif") == 4
    # `hpcmpm plot` under the launcher: rank 0 alone writes the two files (two processes
    # would race on them) and says so once; its table is the one process's.
    assert main(["plot", str(run), "--out", str(tmp_path / "plot1")]) == 0
    proc = mpi_hpcmpm(2, "plot", str(run), "--out", str(tmp_path / "plot2"))
    assert proc.stdout.count("wrote ") == 1, proc.stdout
    assert (tmp_path / "plot2" / "diagnostics.csv").read_text() == \
        (tmp_path / "plot1" / "diagnostics.csv").read_text()

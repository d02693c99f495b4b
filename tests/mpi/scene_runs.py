"""A scene run through the CLI on N ranks with ``--set`` overrides, and its last frame: the
launch helpers the rank-equivalence tests share."""

from __future__ import annotations

from pathlib import Path

from hpcmpm.io.frames import read_frame
from launch import mpi_hpcmpm


def last_frame_and_attrs(out: Path, steps: int, ranks: int | None = None):
    """(fields, attributes) of the last frame in ``out``, which must be at step ``steps``
    and, given ``ranks``, written by one world of that many ranks (not N separate 1-rank
    runs)."""
    data, attrs = read_frame(sorted(out.glob("frame_*.h5"))[-1])
    assert attrs["step"] == steps
    if ranks is not None:
        assert attrs["n_ranks"] == ranks
    return data, attrs


def last_frame(out: Path, steps: int, ranks: int | None = None) -> dict:
    """The fields of the last frame in ``out`` (`last_frame_and_attrs`)."""
    return last_frame_and_attrs(out, steps, ranks)[0]


def hpcmpm(ranks: int, *args, timeout: float = 500, past_cfl: bool = False):
    """`hpcmpm *args` on ``ranks`` ranks (a process group killed on timeout). The rank tests
    fix dt so every rank count takes the same steps; unless ``past_cfl``, that dt must stay
    within the CFL bound throughout."""
    proc = mpi_hpcmpm(ranks, *args, timeout=timeout)
    assert past_cfl or "exceeds the CFL bound" not in proc.stderr
    return proc


def run_scene(ranks: int, scene: str, sets, out: Path, steps: int, *extra,
              past_cfl: bool = False) -> dict:
    """`hpcmpm run scene --set ...` on ``ranks`` ranks (`hpcmpm`); the last frame, at step
    ``steps``."""
    args = ["run", scene, "--out", str(out), "--quiet", "--force", *extra]
    for s in sets:
        args += ["--set", s]
    hpcmpm(ranks, *args, past_cfl=past_cfl)
    return last_frame(out, steps, ranks)

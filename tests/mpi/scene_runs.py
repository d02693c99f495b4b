"""A scene run through the CLI on N ranks with ``--set`` overrides, and its last frame: the
launch helpers the rank-equivalence tests share."""

from pathlib import Path

from hpcmpm.io.frames import read_frame
from test_restart import hpcmpm as launch


def last_frame(out: Path, steps: int) -> dict:
    """The fields of the last frame in ``out``, which must be at step ``steps``."""
    data, attrs = read_frame(sorted(out.glob("frame_*.h5"))[-1])
    assert attrs["step"] == steps
    return data


def run_scene(ranks: int, scene: str, sets, out: Path, steps: int, *extra,
              timeout: float = 500, past_cfl: bool = False) -> dict:
    """`hpcmpm run scene --set ...` on ``ranks`` ranks (a process group killed on timeout);
    the last frame, at step ``steps``. A fixed dt in ``sets`` keeps the steps the same on
    every rank count; unless ``past_cfl``, it must stay within the CFL bound throughout."""
    args = ["run", scene, "--out", str(out), "--quiet", "--force", *extra]
    for s in sets:
        args += ["--set", s]
    proc = launch(ranks, *args, timeout=timeout)
    assert past_cfl or "exceeds the CFL bound" not in proc.stderr
    return last_frame(out, steps)

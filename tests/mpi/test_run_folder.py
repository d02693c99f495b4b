"""A run folder as the user meets it: ``hpcmpm info RUN_FOLDER`` says where the run stands and
how to continue it, and ``hpcmpm restart RUN_FOLDER`` continues from its newest checkpoint, on
2 ranks as a job script would."""

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from hpcmpm.errors import CheckpointError
from hpcmpm.io.frames import read_frame
from hpcmpm.io.info import OutputFileError, describe_run
from launch import mpi_hpcmpm as hpcmpm

DT = 5e-3
FIXED = ["--set", f"simulation.dt={DT}", "--set", f"output.every={50 * DT}"]


def corrupt(path: Path, dataset: str) -> None:
    """One byte of ``dataset``'s data flipped in place."""
    with h5py.File(path, "r") as h5:
        offset = h5[dataset].id.get_offset()
    with open(path, "r+b") as f:
        f.seek(offset)
        byte = f.read(1)[0]
        f.seek(offset)
        f.write(bytes([byte ^ 0xFF]))


def last_frame(out: Path):
    return read_frame(sorted(out.glob("frame_*.h5"))[-1])


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """100 steps of the disks on 2 ranks, checkpoints every 40 steps (80 and the end, 100,
    are kept)."""
    out = tmp_path_factory.mktemp("run")
    hpcmpm(2, "run", "inputs/disks_2d.toml", "--out", str(out), "--quiet", "--end-time",
           str(100 * DT), "--checkpoint-every", "40", *FIXED)
    return out


def test_info_on_a_finished_run(finished):
    lines, code = describe_run(finished)
    assert code == 0
    assert lines[2].startswith("provenance:  run of ") and lines[2].endswith(
        "inputs/disks_2d.toml, not restarted")
    del lines[2]
    assert lines == [
        f"run:         {finished}",
        "scene:       disks_2d",
        "frames:      3: frame_000000.h5 (t = 0) to frame_000002.h5 (t = 0.5)",
        "checkpoints: ckpt_000000080.h5 (step 80, t = 0.4)",
        "             ckpt_000000100.h5 (step 100, t = 0.5)",
        "newest:      ckpt_000000100.h5: ok (every dataset verifies)",
        "end time:    0.5",
        "state:       finished (t = 0.5)",
        f"continue:    hpcmpm restart {finished} --end-time T (T > 0.5)"]


def test_restart_from_the_folder_takes_its_newest_checkpoint(tmp_path, finished):
    """Restarting from step 80 or 100 ends in the same bits, so the restart chain the frames
    record is what tells which checkpoint was taken."""
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    hpcmpm(2, "restart", str(run), "--end-time", str(150 * DT), "--quiet")
    got, attrs = last_frame(run)
    assert attrs["step"] == 150 and attrs["n_ranks"] == 2
    chain = json.loads(attrs["restart_chain"])
    assert Path(chain[-1]) == (run / "ckpt_000000100.h5").resolve()
    # info tells the history, and a single frame in a new folder without a range.
    lines, _ = describe_run(run)
    assert lines[2].endswith(f"restarted from {(run / 'ckpt_000000100.h5').resolve()}")
    # The same as restarting from that file by name, bit for bit.
    by_name = tmp_path / "by_name"
    shutil.copytree(finished, by_name)
    hpcmpm(2, "restart", str(by_name / "ckpt_000000100.h5"), "--end-time", str(150 * DT),
           "--quiet")
    ref, _ = last_frame(by_name)
    for name in ("id", "x", "v", "F"):
        assert np.array_equal(got[name], ref[name]), name


def test_a_restart_from_an_older_checkpoint_warns_of_the_later_output(tmp_path, finished):
    """From step 80 (t = 0.4) to t = 0.45 in the run's own folder: frame_000002 (t = 0.5) and
    ckpt_000000100 lie beyond the checkpoint; the warning names them. From the newest
    checkpoint there is nothing to warn of."""
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    proc = hpcmpm(2, "restart", str(run / "ckpt_000000080.h5"), "--end-time", str(90 * DT),
                  "--quiet")
    warnings = [l for l in proc.stderr.splitlines() if "already holds" in l]
    assert len(warnings) == 1, proc.stderr  # rank 0 alone
    assert ("1 frame(s) (frame_000002.h5 .. frame_000002.h5) and 1 checkpoint(s) "
            "(ckpt_000000100.h5 .. ckpt_000000100.h5) from beyond ckpt_000000080.h5") \
        in warnings[0]
    assert "(to t=0.45)" in warnings[0] and "--out NEW_FOLDER" in warnings[0]
    # What it warned of: the restart's last frame took the name frame_000002 (t = 0.45), the
    # older run's step 100 is still the newest checkpoint.
    assert last_frame(run)[1]["time"] == pytest.approx(0.45)
    assert describe_run(run)[0][-2] == "state:       finished (t = 0.5)"
    proc = hpcmpm(2, "restart", str(run), "--end-time", str(110 * DT), "--quiet")
    assert "already holds" not in proc.stderr


def test_a_stopped_run_is_told_to_continue_and_continues(tmp_path, finished):
    """Without its last checkpoint the run stands at step 80 (t = 0.4) of its 0.5: info says it
    stopped before its end time and gives the plain restart, which runs it to 0.5."""
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    (run / "ckpt_000000100.h5").unlink()
    lines, code = describe_run(run)
    assert code == 0
    assert lines[-3:] == ["end time:    0.5", "state:       stopped at t = 0.4, before its end time",
                          f"continue:    hpcmpm restart {run}"]
    hpcmpm(2, "restart", str(run), "--quiet")
    _, attrs = last_frame(run)
    assert attrs["time"] == pytest.approx(0.5) and attrs["step"] == 100


def test_info_reports_a_damaged_newest_checkpoint_and_missing_frames(tmp_path, finished):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    (run / "frame_000001.h5").unlink()
    corrupt(run / "ckpt_000000100.h5", "/particles/x")
    lines, code = describe_run(run)
    assert code == CheckpointError.exit_code
    assert "             missing from the series: 1 (1)" in lines
    assert lines[-2].startswith("newest:      ckpt_000000100.h5: FAILED: ckpt_000000100.h5: "
                                "checksum mismatch in /particles/x")
    assert "ckpt_000000080.h5 may still be usable" in lines[-2]
    assert lines[-1] == "continue:    not from the newest checkpoint (above)"


def test_a_folder_without_checkpoints_or_output(tmp_path, finished):
    frames_only = tmp_path / "frames_only"
    shutil.copytree(finished, frames_only)
    for ckpt in frames_only.glob("ckpt_*.h5"):
        ckpt.unlink()
    lines, code = describe_run(frames_only)
    # The scene's name from the frames when no checkpoint holds it (was "(unnamed)").
    assert lines[1] == "scene:       disks_2d"
    assert code == 0 and lines[-3:] == [
        "checkpoints: none",
        "end time:    not recorded (frames do not hold it; a checkpoint does)",
        "continue:    not possible without a checkpoint; run the scene again"]
    proc = hpcmpm(2, "restart", str(frames_only), check=False)
    assert proc.returncode == CheckpointError.exit_code
    assert f"{frames_only}: no checkpoint (ckpt_SSSSSSSSS.h5) in this folder" in proc.stderr
    assert "Traceback" not in proc.stderr
    one = tmp_path / "one_frame"
    one.mkdir()
    for name in ("frame_000002.h5", "ckpt_000000100.h5"):
        shutil.copy(finished / name, one / name)
    assert "frames:      1: frame_000002.h5 (t = 0.5)" in describe_run(one)[0]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(OutputFileError, match="not a run folder"):
        describe_run(empty)
    # The frames the run wrote are intact (the failed restart wrote nothing).
    with h5py.File(frames_only / "frame_000002.h5") as f:
        assert f.attrs["step"] == 100


def test_restart_into_another_runs_folder_needs_force(tmp_path, finished):
    """`hpcmpm restart CKPT --out DIR` where DIR holds another run's output: refused as
    `run` refuses it (exit 5, nothing written); it wrote its frames beside the other run's
    before. With --force the other run's output is replaced; into the checkpoint's own
    folder --out is allowed as before."""
    other = tmp_path / "other"
    shutil.copytree(finished, other)          # a run of its own (the same scene, no matter)
    before = sorted(p.name for p in other.iterdir())
    ckpt = finished / "ckpt_000000100.h5"
    proc = hpcmpm(1, "restart", str(ckpt), "--out", str(other), "--end-time", str(110 * DT),
                  "--quiet", check=False)
    assert proc.returncode == 5, proc.stderr
    assert "already holds output of another run" in proc.stderr and "--force" in proc.stderr
    assert sorted(p.name for p in other.iterdir()) == before
    hpcmpm(1, "restart", str(ckpt), "--out", str(other), "--end-time", str(110 * DT),
           "--quiet", "--force")
    # Replaced: only the continuation's own frame and checkpoint are there.
    assert sorted(p.name for p in other.glob("*.h5") if not p.name.startswith("polyvertex")) \
        == ["ckpt_000000110.h5", "frame_000003.h5"]
    own = tmp_path / "own"
    shutil.copytree(finished, own)
    hpcmpm(1, "restart", str(own / "ckpt_000000100.h5"), "--out", str(own), "--end-time",
           str(110 * DT), "--quiet")
    assert (own / "ckpt_000000110.h5").exists() and (own / "frame_000000.h5").exists()


def test_info_on_a_truncated_checkpoint_by_name_and_in_its_folder(tmp_path, finished, capsys):
    """A checkpoint cut short (a copy that did not finish) fails verification whether `info`
    is given the file or its folder: exit 4 and "file is truncated" naming the previous one
    (given the file, `info` exited 6 with HDF5's own message), and the folder's scene name
    comes from the frames (it said "(unnamed)")."""
    from types import SimpleNamespace

    from hpcmpm.io.info import info_command

    run = tmp_path / "run"
    shutil.copytree(finished, run)
    newest = run / "ckpt_000000100.h5"
    data = newest.read_bytes()
    newest.write_bytes(data[:len(data) // 2])
    assert info_command(SimpleNamespace(file=str(newest))) == CheckpointError.exit_code
    out = capsys.readouterr().out.splitlines()
    assert out[-1].startswith("checksum:    FAILED: ckpt_000000100.h5: file is truncated (")
    assert "ckpt_000000080.h5 may still be usable" in out[-1]
    lines, code = describe_run(run)
    assert code == CheckpointError.exit_code
    assert lines[1] == "scene:       disks_2d"
    assert "file is truncated" in lines[-2]
    # A file that is not named as a checkpoint and cannot be opened stays "not readable".
    other = run / "copy.h5"
    other.write_bytes(data[:len(data) // 2])
    with pytest.raises(OutputFileError, match="not a readable HDF5 file"):
        info_command(SimpleNamespace(file=str(other)))

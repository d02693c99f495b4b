"""Command-line values go through the scene's own checks: one line, exit code 2, nothing
written. A restart with nothing left to run says so; a frame given to `restart` names the right
checkpoint. In-process (`cli.main`), so each case costs milliseconds, not an interpreter."""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import pytest

from hpcmpm import cli

BAR = "inputs/bar_2d.toml"
# A fixed dt of 0.01 (half the bar's CFL step, c = 10, dx = 0.5, cfl = 0.4): 0.2 is 20 steps.
SHORT = ["--quiet", "--end-time", "0.2", "--set", "output.every=0.1", "--set", "simulation.dt=0.01",
         "--set", "output.checkpoint_keep=5", "--checkpoint-every", "7"]


def error_lines(capsys) -> list[str]:
    return [l for l in capsys.readouterr().err.splitlines() if l.startswith("hpcmpm:")]


BAD_RUN_OPTIONS = {
    "end_time_zero": (["--end-time", "0"], "--end-time: must be > 0.0, got 0.0"),
    "end_time_negative": (["--end-time", "-1"], "--end-time: must be > 0.0, got -1.0"),
    "end_time_nan": (["--end-time", "nan"], "--end-time: must be finite, got nan"),
    "checkpoint_every_zero": (["--checkpoint-every", "0"],
                              "--checkpoint-every: must be >= 1, got 0"),
    "checkpoint_wall_nan": (["--checkpoint-wall", "nan"],
                            "--checkpoint-wall: expected a positive HH:MM:SS, got 'nan'"),
    "checkpoint_wall_zero": (["--checkpoint-wall", "00:00:00"],
                             "--checkpoint-wall: expected a positive HH:MM:SS, got '00:00:00'"),
    "checkpoint_wall_text": (["--checkpoint-wall", "1h"],
                             "--checkpoint-wall: expected HH:MM:SS, got '1h'"),
    "checkpoint_wall_four_fields": (["--checkpoint-wall", "1:00:00:00"],
                                    "--checkpoint-wall: expected a positive HH:MM:SS, got "
                                    "'1:00:00:00'"),
    # A frame every 0.1 to t = 1e5: a million files, and steps shortened to land on each.
    "end_time_too_many_frames": (["--set", "output.every=0.1", "--end-time", "1e5"],
                                 "--end-time: output.every = 0.1 would write 1e+06 frames to "
                                 "t = 100000, a file each (at most 100000): raise "
                                 "output.every"),
    # A negative field was added in (01:-30:00 was half an hour).
    "checkpoint_wall_negative_field": (["--checkpoint-wall", "01:-30:00"],
                                       "--checkpoint-wall: expected a positive HH:MM:SS, got "
                                       "'01:-30:00'"),
}


@pytest.mark.parametrize("case", BAD_RUN_OPTIONS)
def test_bad_run_option_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, case):
    extra, expected = BAD_RUN_OPTIONS[case]
    out = tmp_path / "out"
    assert cli.main(["run", BAR, "--out", str(out), "--quiet", *extra]) == 2
    assert error_lines(capsys) == [f"hpcmpm: error: {expected}"]
    assert not out.exists()


def test_out_that_is_a_file_is_one_line_exit_2(tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("not a folder")
    for out in (target, target / "below"):
        assert cli.main(["run", BAR, "--out", str(out), "--quiet"]) == 2
        what = "is" if out == target else f"lies under {target}, which is"
        assert error_lines(capsys) == [f"hpcmpm: error: --out: {out} {what} a file, not a folder"]
    assert target.read_text() == "not a folder"


def test_out_that_cannot_be_created_is_one_line_exit_2(tmp_path, capsys):
    """An --out the system refuses is one line naming it and the system's reason, exit 2:
    a folder name too long (the check of the options: was an OSError traceback) and a folder
    that mkdir cannot make (/proc takes none)."""
    too_long = tmp_path / ("x" * 300) / "run"
    assert cli.main(["run", BAR, "--out", str(too_long), "--quiet"]) == 2
    assert error_lines(capsys) == [f"hpcmpm: error: --out: cannot create {too_long}: "
                                   f"File name too long"]
    if Path("/proc").is_dir():
        assert cli.main(["run", BAR, "--out", "/proc/hpcmpm_run", "--quiet"]) == 2
        (line,) = error_lines(capsys)
        assert line.startswith("hpcmpm: error: --out: cannot create /proc/hpcmpm_run: "), line


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """20 steps of the bar: frames at steps 0, 10, 20; checkpoints at 7, 14 and 20."""
    out = tmp_path_factory.mktemp("bar")
    assert cli.main(["run", BAR, "--out", str(out), *SHORT]) == 0
    return out


def test_short_run_layout(short_run):
    # The cases below rely on these steps; a change of the bar's time step would show here.
    with h5py.File(short_run / "frame_000001.h5") as f:
        assert int(f.attrs["step"]) == 10
    assert sorted(p.name for p in short_run.glob("ckpt_*.h5")) == [
        f"ckpt_{s:09d}.h5" for s in (7, 14, 20)]


def test_restart_with_nothing_left_says_so_and_writes_nothing(short_run, capsys):
    before = {p.name: p.stat().st_mtime_ns for p in short_run.iterdir()}
    final = short_run / "ckpt_000000020.h5"
    assert cli.main(["restart", str(final), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"hpcmpm: nothing to run: {final} is at t=0.2, the end time")
    assert "output:" not in captured.out
    assert {p.name: p.stat().st_mtime_ns for p in short_run.iterdir()} == before
    # An explicit end time that is not later is a mistake in the arguments.
    assert cli.main(["restart", str(final), "--end-time", "0.1", "--quiet"]) == 2
    assert error_lines(capsys) == [
        "hpcmpm: error: --end-time: must be later than the checkpoint's time t=0.2 "
        "(ckpt_000000020.h5), got 0.1"]
    for bad, line in (("-1", "--end-time: must be > 0.0, got -1.0"),
                      ("nan", "--end-time: must be finite, got nan"),
                      ("1e5", "--end-time: output.every = 0.1 would write 1e+06 frames to t = "
                              "100000, a file each (at most 100000): raise output.every")):
        assert cli.main(["restart", str(final), "--end-time", bad, "--quiet"]) == 2
        assert error_lines(capsys) == [f"hpcmpm: error: {line}"]
    assert {p.name: p.stat().st_mtime_ns for p in short_run.iterdir()} == before


def test_restart_of_a_frame_names_the_checkpoint_before_it(short_run, capsys):
    frame = short_run / "frame_000001.h5"  # step 10: checkpoint 7 is the one, not 14 or 20
    assert cli.main(["restart", str(frame), "--quiet"]) == 4
    assert error_lines(capsys) == [
        f"hpcmpm: error: frame_000001.h5: is a frame, not a checkpoint (restart reads "
        f"ckpt_*.h5 files); the newest checkpoint at or before its step 10 is "
        f"{short_run / 'ckpt_000000007.h5'}"]


def test_signal_stop_is_not_labelled_an_error(capsys, monkeypatch):
    from hpcmpm.runner import CheckpointedOnSignal

    def stopped(args):
        raise CheckpointedOnSignal("SIGUSR1 received: checkpoint written at step 3")

    monkeypatch.setattr(cli, "_run", stopped)
    assert cli.main(["run", BAR]) == 75
    assert error_lines(capsys) == [
        "hpcmpm: stopped: SIGUSR1 received: checkpoint written at step 3"]


def test_errors_are_printed_by_rank_0_only(capsys, monkeypatch):
    # Under mpiexec every rank raises the same error (errors.HpcmpmError): one message per job.
    monkeypatch.setenv("PMI_RANK", "1")
    assert cli.main(["run", BAR, "--end-time", "-1"]) == 2
    assert error_lines(capsys) == []
    monkeypatch.setenv("PMI_RANK", "0")
    assert cli.main(["run", BAR, "--end-time", "-1"]) == 2
    assert len(error_lines(capsys)) == 1


def test_info_names_the_scene_and_the_provenance_alike_for_frames_and_checkpoints(short_run,
                                                                                 capsys):
    scene = Path(BAR).resolve()
    for name in ("frame_000001.h5", "ckpt_000000014.h5"):
        assert cli.main(["info", str(short_run / name)]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert "scene:       bar_2d" in lines, lines
        assert f"provenance:  run of {scene}, not restarted" in lines, lines


def test_frame_times_are_the_decimal_times_the_scene_asks_for():
    from hpcmpm.runner import frame_time

    # 33 * 0.1 is 3.3000000000000003 in binary; the frame is written at 3.3.
    assert 33 * 0.1 != 3.3 and frame_time(33, 0.1, 10.0) == 3.3
    assert repr(frame_time(3, 0.1, 10.0)) == "0.3" and frame_time(200, 0.1, 10.0) == 10.0
    times = [frame_time(k, 0.07, 5.0) for k in range(73)]  # 72 x 0.07 > 5: the end
    assert times == sorted(set(times)) and times[-1] == 5.0
    # Never more than an ulp or two from k * every: the schedule is the same.
    assert all(abs(frame_time(k, 0.07, 1e9) - k * 0.07) <= 2 * math.ulp(k * 0.07)
               for k in range(1, 10000))


def test_restart_restores_the_time_step_state(tmp_path, caplog, monkeypatch):
    import logging

    from hpcmpm import runner

    # A fixed dt 6 % above the bar's CFL bound (0.0198): warned once in the first run.
    out = tmp_path / "warned"
    fixed = ["--quiet", "--set", "simulation.dt=0.021", "--set", "output.every=0.105"]
    with caplog.at_level(logging.WARNING):
        assert cli.main(["run", BAR, "--out", str(out), "--end-time", "0.105", *fixed]) == 0
    assert sum("exceeds the CFL bound" in r.message for r in caplog.records) == 1
    caplog.clear()
    seen = {}
    original = runner.Runner.run

    def spy(self):
        seen.update(last_dt=self.last_dt, dt_warned=self.dt_warned)
        return original(self)

    monkeypatch.setattr(runner.Runner, "run", spy)
    with caplog.at_level(logging.WARNING):
        assert cli.main(["restart", str(out / "ckpt_000000005.h5"), "--end-time", "0.21",
                         "--quiet"]) == 0
    assert seen == {"last_dt": pytest.approx(0.021), "dt_warned": True}
    assert not any("exceeds the CFL bound" in r.message for r in caplog.records)


def test_restart_restores_the_largest_step(tmp_path, monkeypatch):
    """`Runner.check_collapse` measures the step against the largest the run has taken; a
    restart takes that from its checkpoint, so it decides as the run it continues would."""
    from hpcmpm import runner

    peaks = []
    original = runner.Runner.run

    def spy(self):
        peaks.append(self.dt_peak)      # at the start: 0 for a new run, restored otherwise
        result = original(self)
        peaks.append(self.dt_peak)
        return result

    monkeypatch.setattr(runner.Runner, "run", spy)
    out = tmp_path / "bar"
    assert cli.main(["run", BAR, "--out", str(out), "--end-time", "0.105", "--quiet",
                     "--set", "output.every=0.105"]) == 0
    checkpoint = max(out.glob("ckpt_*.h5"))
    assert cli.main(["restart", str(checkpoint), "--end-time", "0.21", "--quiet"]) == 0
    assert peaks[0] == 0.0 and peaks[1] > 0.0
    assert peaks[2] == peaks[1]


def test_restart_reports_fields_it_drops_or_fills_in_one_line(short_run, caplog, monkeypatch,
                                                             tmp_path):
    import logging

    from hpcmpm.io import checkpoint

    original = checkpoint.read_checkpoint

    def other_version(path, domain):
        fields, meta = original(path, domain)
        fields["Jp_old"] = fields.pop("C")[:, 0, 0].copy()  # one field renamed
        return fields, meta

    monkeypatch.setattr(checkpoint, "read_checkpoint", other_version)
    with caplog.at_level(logging.WARNING):
        assert cli.main(["restart", str(short_run / "ckpt_000000014.h5"), "--end-time", "0.15",
                         "--out", str(tmp_path / "again"), "--quiet"]) == 0
    lines = [r.message for r in caplog.records if "restart from" in r.message]
    assert lines == ["restart from ckpt_000000014.h5 drops checkpoint fields this run does not "
                     "declare: Jp_old; starts declared fields the checkpoint lacks from their "
                     "defaults: C"]

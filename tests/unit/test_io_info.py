"""``hpcmpm info``: frames and checkpoints described, bad files as one-line HpcmpmErrors."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from test_io_checkpoint import flip_bytes_in, write
from test_io_frames import global_particles, write_frames

from hpcmpm.errors import CheckpointError, HpcmpmError
from hpcmpm.io.info import describe, info_command, scene_name


def test_info_on_a_frame(tmp_path, capsys):
    path = write_frames(tmp_path, global_particles(3, 30), 3, 2, times=(0.0, 0.125))[1]
    assert info_command(SimpleNamespace(file=path)) == 0
    out = capsys.readouterr().out
    for expected in ("kind:        frame", "scene:       frame test", "time:        0.125",
                     "step:        10", "dim:         3", "particles:   30", "ranks:       2",
                     "version:     hpcmpm", "provenance:  run of a.toml, not restarted",
                     "/particles/x",
                     "(30, 3)", "float64", "/particles/material", "int32"):
        assert expected in out, expected
    assert "checksum" not in out


def test_info_on_a_checkpoint(tmp_path, capsys):
    path, _ = write(tmp_path, 2, step=100)
    assert info_command(SimpleNamespace(file=str(path))) == 0
    out = capsys.readouterr().out
    for expected in ("kind:        checkpoint", "scene:       ckpt", "step:        100",
                     "particles:   127", "/particles/Fp", "/meta/boxes",
                     "checksum:    ok"):
        assert expected in out, expected
    flip_bytes_in(path, "/particles/v")
    assert info_command(SimpleNamespace(file=str(path))) == CheckpointError.exit_code
    assert "checksum:    FAILED: ckpt_000000100.h5: checksum mismatch in /particles/v" in \
        capsys.readouterr().out


@pytest.mark.parametrize("content,message", [(None, "no such file"),
                                             (b"not hdf5", "not a readable HDF5 file")])
def test_info_on_bad_files(tmp_path, content, message):
    path = tmp_path / "x.h5"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(HpcmpmError, match=message) as err:
        describe(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_scene_name_sources():
    assert scene_name('name = "dam"') == "dam"
    assert scene_name('[scene]\nname = "snow"') == "snow"
    assert scene_name("broken = [", "/a/b/sand.toml") == "sand"
    assert scene_name("") == "(unnamed)"


def test_provenance_line_says_what_the_chain_is():
    from hpcmpm.io.info import provenance

    assert provenance(["/s/disks_2d.toml"]) == "run of /s/disks_2d.toml, not restarted"
    assert provenance(["/s/d.toml", "/r/ckpt_000000100.h5", "/r/ckpt_000000200.h5"]) == \
        "run of /s/d.toml, restarted from /r/ckpt_000000100.h5, then /r/ckpt_000000200.h5"


def test_info_reports_the_frame_index_version_and_full_time(tmp_path, capsys):
    """The frame line is the file's frame index (1 for the second frame, at step 10), the
    version is the one that wrote it, the time keeps 9 significant digits."""
    import hpcmpm

    path = write_frames(tmp_path, global_particles(2, 10), 2, 1,
                        times=(0.0, 0.123456789))[1]
    assert info_command(SimpleNamespace(file=path)) == 0
    out = capsys.readouterr().out.splitlines()
    assert "frame:       1" in out and "step:        10" in out
    assert f"version:     hpcmpm {hpcmpm.__version__}" in out
    assert "time:        0.123456789" in out

"""A blow-up stops the run with step, time, particle ids, material and a hint (exit code 3);
the frames already written stay readable and hold no NaN."""

import sys
from pathlib import Path

import h5py
import numpy as np
from launch import run_in_group


def test_too_large_fixed_dt_stops_with_a_clear_message(tmp_path):
    exe = Path(sys.executable).with_name("hpcmpm")
    out = tmp_path / "out"
    # 50x the CFL bound of this scene: the explicit update is violently unstable.
    proc = run_in_group(
        [str(exe), "run", "inputs/disks_2d.toml", "--out", str(out), "--quiet",
         "--set", "simulation.dt=0.3", "--set", "output.every=0.6", "--end-time", "30"],
        timeout=120)
    assert proc.returncode == 3, proc.stderr
    assert "Traceback" not in proc.stderr
    message = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
    assert len(message) == 1
    for part in ("numerical instability at step", "t=", "ids", "material 'rubber'",
                 "lower simulation.cfl"):
        assert part in message[0], message[0]
    assert "exceeds the CFL bound" in proc.stderr  # the fixed dt warned first
    frames = sorted(out.glob("frame_*.h5"))
    assert frames, "the frame at t = 0 was written before the blow-up"
    for frame in frames:
        with h5py.File(frame) as f:
            for name in ("x", "v", "F"):
                assert np.all(np.isfinite(f[f"particles/{name}"][...])), frame
    assert not list(out.glob("*.tmp"))

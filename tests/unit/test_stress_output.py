"""The Kirchhoff stress is not stored per particle (it lives in a chunk buffer between the
material kernel and P2G), but ``output.fields = ["tau"]`` still writes it: computed at frame
time on copies of the material state, so asking for it must not change the run."""

import sys
from pathlib import Path

import h5py
import numpy as np

from hpcmpm.materials import make_material
from hpcmpm.scene import parse_scene
from launch import run_in_group

SNOW = Path("inputs/snow_block_3d.toml").read_text()


def run(tmp_path: Path, name: str, fields: str) -> Path:
    text = (SNOW.replace('fields = ["Jp"]', f"fields = {fields}")
            .replace("end_time = 0.25", "end_time = 0.02").replace("every = 0.0125", "every = 0.01")
            .replace("dx = 0.025", "dx = 0.05"))
    scene = tmp_path / f"{name}.toml"
    scene.write_text(text)
    out = tmp_path / name
    exe = Path(sys.executable).with_name("hpcmpm")
    proc = run_in_group([str(exe), "run", str(scene), "--out", str(out), "--quiet"],
                        timeout=300)
    assert proc.returncode == 0, proc.stderr
    return out


def test_stress_output_matches_the_model_and_does_not_change_the_run(tmp_path):
    with_tau = run(tmp_path, "with_tau", '["Jp", "tau"]')
    without = run(tmp_path, "without", '["Jp"]')
    last = sorted(p.name for p in with_tau.glob("frame_*.h5"))[-1]
    with h5py.File(with_tau / last) as a, h5py.File(without / last) as b:
        assert "tau" not in b["particles"]
        # Same arithmetic in the same order: bitwise equal.
        for name in ("x", "v", "F", "Jp"):
            assert np.array_equal(a["particles"][name][...], b["particles"][name][...]), name
        tau = a["particles"]["tau"][...]
        F = a["particles"]["F"][...]
        Jp = a["particles"]["Jp"][...]
        scene_text = a.attrs["scene"]
    scene = parse_scene(scene_text, path="<frame>")
    n = len(F)
    assert tau.shape == (n, 3, 3) and np.all(np.isfinite(tau))
    assert np.abs(tau).max() > 0.0  # the block has been loaded by gravity and the sphere
    # The snow model's own stress on the written state (F is the clamped elastic part, so
    # the projection leaves it alone): equal up to round-off of the same kernel.
    material = make_material(scene.materials[0], 3)
    fields = {"F": F.copy(), "Fp": np.tile(np.eye(3), (n, 1, 1)), "Jp": Jp.copy(),
              "tau": np.empty_like(tau), "vol0": np.ones(n)}
    material.update_stress(fields, 0.0)
    assert np.allclose(fields["tau"], tau, rtol=1e-12, atol=1e-12 * np.abs(tau).max())

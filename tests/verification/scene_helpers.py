"""Run a scene file in process and return its particles, for the invariance tests
(orientation, Galilean boosts) that compare two runs of one scene particle by particle."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import tomli_w

from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
from hpcmpm.scene import load_scene
from hpcmpm.simulation import Simulation

FIELDS = ("id", "x", "v", "F", "model", "damage")
INPUTS = Path(__file__).resolve().parents[2] / "inputs"


def write_scene(folder: Path, scene: str, raw: dict) -> Path:
    """Write the parsed scene ``raw`` as ``folder/scene.toml`` (folder made new), with the
    mesh files of inputs/ beside it when a body reads one (the path is relative)."""
    folder.mkdir()
    path = folder / f"{scene}.toml"
    path.write_text(tomli_w.dumps(raw))
    if any(body.get("shape") == "mesh" for body in raw.get("bodies", [])):
        shutil.copytree(INPUTS / "meshes", folder / "meshes")
    return path


def run_scene(path: Path, fields=FIELDS) -> tuple[dict, dict]:
    """Run the scene at ``path`` to its end time (output in its folder). Returns the initial
    position of each particle id and the final ``fields`` present (None: all), rows in id
    order, with "steps" and "time", the steps taken and the time reached."""
    scene = load_scene(str(path))
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    start = {int(i): x.copy() for i, x in zip(sim.particles["id"], sim.particles["x"])}
    Runner(sim, None, RunOptions(out_dir=path.parent, end_time=scene.end_time,
                                quiet=True)).run()
    p = sim.particles
    order = np.argsort(p["id"])
    names = p.field_names() if fields is None else [k for k in fields if k in p]
    out = {k: np.array(p[k][order]) for k in names}
    out["steps"] = sim.step_index
    out["time"] = sim.time
    return start, out

#!/usr/bin/env python
"""Stability study: CFL sweeps, extreme cases, energy drift per transfer scheme.

(i)   CFL sweep per transfer scheme on the axial bar (inputs/bar_2d.toml) and the colliding
      disks (inputs/disks_2d.toml, coarsened and shortened). A run is stable when it finishes
      with a finite state and its total energy never exceeds 1.05x its initial value; an
      `InstabilityError` (NaN or det F <= 0) counts as unstable. Reported: the largest CFL
      below the first unstable one ("largest stable CFL").
(ii)  Extreme cases, each of which must either finish with finite, bounded energy or stop with
      an `InstabilityError` whose message names the step, the time and particle ids:
      sponge twisted two full turns (inputs/sponge_twist_3d.toml), a kinematic sphere collider
      ("bullet") at half the P-wave speed into an elastic block (2D), the jelly cube with a
      fixed dt of 5x the CFL limit dx / (c + |v|max). The jelly case is also run through the
      CLI (`hpcmpm run ... --out DIR`, exit code 3 expected) and every frame it wrote is
      checked to hold only finite numbers.
(iii) Energy drift per transfer scheme on the disks: (E_end - E_0) / E_0.

    python scripts/study_stability.py           # full study (a few minutes on 2 cores)
    python scripts/study_stability.py --smoke   # tiny sizes (seconds)

Writes bench_results/study_stability.json and bench_results/study_stability.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hpcmpm.errors import InstabilityError  # noqa: E402
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain  # noqa: E402
from hpcmpm.scene import load_scene, parse_scene  # noqa: E402
from hpcmpm.simulation import Simulation  # noqa: E402

TRANSFERS = ("pic", "flip", "apic", "mls")
CFLS = (0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.2, 1.5)
MESSAGE = re.compile(r"step \d+, t=[-+.\deE]+: .*ids \d+")


def run_case(scene, end_time: float, energy_limit: float | None = 1.05) -> dict:
    """Run in-process, tracking total energy after every step."""
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    e0 = sim.diagnostics()["total_energy"]
    peak = [e0]

    def observe(s):
        peak[0] = max(peak[0], s.diagnostics()["total_energy"])

    out = {"E0": float(e0)}
    t0 = time.perf_counter()
    try:
        Runner(sim, None, RunOptions(out_dir=Path("."), end_time=end_time, quiet=True),
               observer=observe).run()
        d = sim.diagnostics()
        finite = all(np.isfinite(sim.particles[k]).all() for k in ("x", "v", "F"))
        out.update(finished=True, finite=bool(finite), E_end=float(d["total_energy"]),
                   error=None)
    except InstabilityError as exc:
        out.update(finished=False, finite=False, E_end=math.nan, error=str(exc),
                   message_names_step_time_ids=bool(MESSAGE.search(str(exc))))
    out.update(E_peak=float(peak[0]), E_peak_ratio=float(peak[0] / e0) if e0 > 0 else None,
               steps=sim.step_index,
               t_stop=float(sim.time), wall_s=time.perf_counter() - t0)
    out["stable"] = bool(out["finished"] and out["finite"] and
                         (energy_limit is None or peak[0] <= energy_limit * e0))
    return out


# -- (i) CFL sweep ------------------------------------------------------------------------------
def cfl_sweep(smoke: bool) -> dict:
    cfls = (0.3, 1.2) if smoke else CFLS
    scenes = {
        "bar": ("inputs/bar_2d.toml", ["simulation.dx=1.0"] if smoke else [],
                1.0 if smoke else 10.0),
        "disks": ("inputs/disks_2d.toml", ["simulation.dx=0.1" if smoke else "simulation.dx=0.04"],
                  0.3 if smoke else 2.0),
    }
    result = {}
    for name, (path, extra, end) in scenes.items():
        result[name] = {}
        for tr in TRANSFERS:
            runs = []
            for cfl in cfls:
                scene = load_scene(REPO / path, extra + [f'simulation.transfer="{tr}"',
                                                         f"simulation.cfl={cfl}",
                                                         f"simulation.end_time={end}"])
                r = run_case(scene, end)
                r.pop("error", None)
                runs.append({"cfl": cfl, **r})
                print(f"cfl {name:5s} {tr:5s} {cfl:4.2f}: stable={r['stable']} "
                      f"peak E/E0={r['E_peak_ratio']} steps={r['steps']}", flush=True)
            largest = None
            for r in runs:
                if not r["stable"]:
                    break
                largest = r["cfl"]
            result[name][tr] = {"largest_stable_cfl": largest,
                                "stable_cfls": [r["cfl"] for r in runs if r["stable"]],
                                "runs": runs}
    return result


# -- (ii) extreme cases -------------------------------------------------------------------------
BULLET = """
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 1.0] }}
dx = {dx}
particles_per_cell = 2
kernel = "quadratic"
transfer = "mls"
cfl = 0.4
end_time = {end}

[[materials]]
name = "block"
type = "neo_hookean"
density = 1000.0
E = 1.0e4
nu = 0.3

[[bodies]]
name = "block"
material = "block"
shape = "box"
lower = [0.3, 0.0]
upper = [0.7, 0.4]

[[colliders]]
name = "bullet"
shape = "sphere"
center = [0.5, 0.48]
radius = 0.05
velocity = [0.0, {speed}]
condition = "sticky"

[walls]
default = "slip"
y_lower = {{ condition = "sticky" }}
"""


def summarize(r: dict) -> dict:
    ok = (r["finished"] and r["finite"]) or (not r["finished"] and
                                              r.get("message_names_step_time_ids", False))
    outcome = "finished" if r["finished"] else "InstabilityError"
    return {**r, "outcome": outcome, "acceptable": bool(ok)}


def hpcmpm_cmd() -> list[str]:
    exe = shutil.which("hpcmpm")
    return [exe] if exe else [sys.executable, "-m", "hpcmpm.cli"]


def frames_finite(out_dir: Path) -> tuple[int, bool]:
    import h5py

    frames = sorted(out_dir.glob("frame_*.h5"))
    bad = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind in "fc":
            if not np.isfinite(obj[()]).all():
                bad.append(name)

    for f in frames:
        with h5py.File(f, "r") as h:
            h.visititems(visit)
            for k, v in h.attrs.items():
                a = np.asarray(v)
                if a.dtype.kind in "fc" and not np.isfinite(a).all():
                    bad.append(f"{f.name}:@{k}")
    return len(frames), not bad


def extreme_cases(smoke: bool) -> dict:
    out = {}
    # Sponge twisted two full turns by the end time: omega = 2 turns * 2 pi / end_time.
    end = 0.05 if smoke else 1.0
    omega = 2 * 2 * math.pi / 1.0
    scene = load_scene(REPO / "inputs/sponge_twist_3d.toml",
                       ["simulation.dx=0.05", f"simulation.end_time={end}",
                        f"prescribed.1.angular_velocity=[{omega}, 0.0, 0.0]"])
    r = summarize(run_case(scene, end, energy_limit=None))
    r["turns"] = omega * r["t_stop"] / (2 * math.pi)
    out["sponge_two_turns"] = r
    print(f"sponge: {r['outcome']} at t={r['t_stop']:.3g} ({r['turns']:.2f} turns), "
          f"peak E {r['E_peak']:.3g} (E0 {r['E0']:.3g})", flush=True)

    # Bullet: sphere collider at half the block's P-wave speed, downwards into the block.
    probe = parse_scene(BULLET.format(dx=0.05, end=0.1, speed=0.0))
    c = Simulation(probe, make_domain(probe)).max_wave_speed()
    speed = 0.5 * c
    end = 0.02 if smoke else 0.12
    scene = parse_scene(BULLET.format(dx=0.025 if smoke else 0.01, end=end, speed=-speed),
                        path="<bullet>")
    r = summarize(run_case(scene, end, energy_limit=None))
    r["bullet_speed"], r["wave_speed"] = speed, c
    out["bullet_half_wave_speed"] = r
    print(f"bullet: {r['outcome']} at t={r['t_stop']:.3g}, peak E {r['E_peak']:.3g}"
          + (f"; {r['error'][:120]}" if r["error"] else ""), flush=True)

    # Jelly cube with a fixed dt of 5x the CFL limit dx / (c + |v|max).
    end = 0.2 if smoke else 0.8
    base = ["simulation.dx=0.05", f"simulation.end_time={end}"]
    probe = load_scene(REPO / "inputs/jelly_cube_3d.toml", base)
    sim = Simulation(probe, make_domain(probe))
    initial_particles(sim)
    limit = probe.dx / (sim.max_wave_speed() + sim.check_health())
    dt = 5 * limit
    overrides = base + [f"simulation.dt={dt!r}"]
    r = summarize(run_case(load_scene(REPO / "inputs/jelly_cube_3d.toml", overrides), end,
                           energy_limit=None))
    r["dt"], r["cfl_limit_dt"] = dt, limit
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = Path(tmp) / "jelly"
        cmd = hpcmpm_cmd() + ["run", str(REPO / "inputs/jelly_cube_3d.toml"), "--out",
                              str(out_dir), "--quiet"]
        for o in overrides:
            cmd += ["--set", o]
        env = dict(os.environ, NUMBA_NUM_THREADS="1")
        p = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
        n_frames, finite = frames_finite(out_dir)
        r["cli"] = {"exit_code": p.returncode, "frames": n_frames, "all_frames_finite": finite,
                    "stderr_tail": p.stderr.strip().splitlines()[-1:] if p.stderr else []}
    out["jelly_dt_5x_cfl"] = r
    print(f"jelly: {r['outcome']} at t={r['t_stop']:.3g}; CLI exit {r['cli']['exit_code']}, "
          f"{n_frames} frames, all finite: {finite}", flush=True)
    return out


# -- (iii) energy drift -------------------------------------------------------------------------
def energy_drift(smoke: bool) -> dict:
    extra = ["simulation.dx=0.1", "simulation.end_time=0.3"] if smoke else []
    end = 0.3 if smoke else 3.0
    out = {}
    for tr in TRANSFERS:
        scene = load_scene(REPO / "inputs/disks_2d.toml", extra + [f'simulation.transfer="{tr}"'])
        r = run_case(scene, end, energy_limit=None)
        drift = (r["E_end"] - r["E0"]) / r["E0"] if r["finished"] else math.nan
        out[tr] = {"relative_energy_change": drift, "E0": r["E0"], "E_end": r["E_end"],
                   "E_peak_ratio": r["E_peak_ratio"], "steps": r["steps"]}
        print(f"drift {tr:5s}: {drift:+.4f}", flush=True)
    return out


def table(result: dict) -> str:
    lines = ["| scheme | bar: largest stable CFL | disks: largest stable CFL | "
             "disks energy change |", "|---|---|---|---|"]
    for tr in TRANSFERS:
        lines.append(f"| {tr} | {result['cfl']['bar'][tr]['largest_stable_cfl']} | "
                     f"{result['cfl']['disks'][tr]['largest_stable_cfl']} | "
                     f"{result['energy_drift'][tr]['relative_energy_change']:+.4f} |")
    lines += ["", "| extreme case | outcome | stopped at t | E0 | peak E | notes |",
              "|---|---|---|---|---|---|"]
    for name, r in result["extreme"].items():
        note = ""
        if name == "jelly_dt_5x_cfl":
            note = (f"dt = {r['dt']:.3g} (5x {r['cfl_limit_dt']:.3g}); CLI exit "
                    f"{r['cli']['exit_code']}, {r['cli']['frames']} frames, all finite: "
                    f"{r['cli']['all_frames_finite']}")
        elif name == "sponge_two_turns":
            note = f"{r['turns']:.2f} turns reached"
        elif name == "bullet_half_wave_speed":
            note = f"bullet {r['bullet_speed']:.3g} m/s, c = {r['wave_speed']:.3g} m/s"
        if r.get("error"):
            note += f"; message names step/time/ids: {r.get('message_names_step_time_ids')}"
        lines.append(f"| {name} | {r['outcome']} | {r['t_stop']:.4g} | "
                     f"{r['E0']:.4g} | {r['E_peak']:.4g} | {note} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, short runs")
    ap.add_argument("--out-dir", default=str(REPO / "bench_results"))
    args = ap.parse_args(argv)
    result = {"smoke": args.smoke, "cfl": cfl_sweep(args.smoke),
              "extreme": extreme_cases(args.smoke), "energy_drift": energy_drift(args.smoke)}
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "study_stability.json").write_text(json.dumps(result, indent=1, default=float))
    md = table(result)
    (out / "study_stability.md").write_text(md)
    print(md)
    ok = all(r["acceptable"] for r in result["extreme"].values()) and \
        result["extreme"]["jelly_dt_5x_cfl"]["cli"]["all_frames_finite"]
    if not ok:
        print("an extreme case neither finished with finite state nor stopped with a "
              "proper InstabilityError, or NaN reached an output frame", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

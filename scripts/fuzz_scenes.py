#!/usr/bin/env python
"""Random mutations of the shipped scenes at scale: the mutations of
tests/unit/test_scene_fuzz.py (wrong types, signs, huge and tiny values, NaN, infinities,
missing and extra keys), many more of them than CI runs, and optionally run.

    python scripts/fuzz_scenes.py validate --count 60000 --seed 2 --depth 3
    python scripts/fuzz_scenes.py run --seconds 900 --seed 12

validate: each mutated scene (1 to --depth mutations) goes through what `hpcmpm validate`
runs. A verdict is a valid scene or `SceneError` lines that start with the file's name;
anything else, a RuntimeWarning included, is a failure.

run: the scenes at one particle per cell (those below 30 000 particles then), mutated once;
each that validates is run in this process by `hpcmpm run` to five of its stable steps. A
verdict is an exit code of 0, 2, 3 or 4 (hpcmpm's one-line errors); any other code, any
exception and a run, start-up included, longer than --alarm seconds are failures (numpy's
floating-point errors are logged, as the command line does:
`cli.floating_point_errors_logged`).

Failures are printed once per place they were raised, with the scene and the mutation. Exit
code 1 when there was one. What the campaigns of stop 38 found (280 000 validations, 2 113
runs): a horizon typo that ran validate out of memory, cylinder axes and radii that gave NaN
bounds, an output interval that made a run crawl, a velocity whose square overflowed into a
time step of 0, a material kernel's ZeroDivisionError traceback (all fixed). Stop 39's
(7 898 runs, seeds 101 and 202): a mesh scene that counted its lattice for hours, a
MemoryError traceback from a grid block spanning a periodic axis, a collider too large for
int64 node indices that acted on nothing, a stiffness beyond the float range that skipped
the semi-implicit solve, numpy warnings before the one-line errors (all fixed). Stop 41's
(seed 405, 4 259 runs): a Grueneisen parameter of 9.2e18 whose runaway wave speed made the
time step collapse to 1.5e-22 with every value finite (fixed at stop 42: the run stops at
a million-fold collapse, `Runner.check_collapse`). Stop 42's (seed 406, 10 000 runs: none;
seed 407, 6 045 runs): that guard's message divided by a bound of 0 (eos.gamma0 = 2e300 on
taylor_cu_3d), and an overflowing pressure was reported as the EOS's singular compression
(both fixed). Stop 43's (seed 408, 9 602 runs): none."""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import random
import shutil
import signal
import sys
import tempfile
import time
import tomllib
import traceback
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "unit"))

from hpcmpm import cli  # noqa: E402
from hpcmpm.errors import HpcmpmError  # noqa: E402
from hpcmpm.geometry import estimate_body_counts  # noqa: E402
from hpcmpm.scene import load_scene, parse_scene  # noqa: E402
from hpcmpm.startup import validate_report  # noqa: E402
from test_scene_fuzz import INPUTS, mutate, verdict  # noqa: E402

RUN_PARTICLES = 30_000
RUN_STEPS = 5
VERDICTS = (0, 2, 3, 4)


class Alarm(Exception):
    pass


def where(exc: BaseException) -> tuple[str, str, int]:
    """The exception's type and the last place in hpcmpm it passed (numpy's own line says
    nothing about which call of ours overflowed)."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if "/hpcmpm/" in f.filename.replace("\\", "/")]
    frame = (ours or frames)[-1]
    return type(exc).__name__, Path(frame.filename).name, frame.lineno


def validate(scenes, rng, count: int, depth: int, failures: dict) -> dict:
    verdicts = {"ok": 0, "rejected": 0}
    for _ in range(count):
        path = rng.choice(list(scenes))
        raw, changes = scenes[path], []
        for _ in range(rng.randint(1, depth)):
            raw, change = mutate(raw, rng)
            changes.append(change)
        try:
            text = tomli_w.dumps(raw)
        except (TypeError, ValueError):  # a mutation TOML cannot hold
            continue
        try:
            verdicts[verdict(path, text)] += 1
        except Exception as exc:  # noqa: BLE001 - the point
            failures.setdefault(where(exc), (path, changes, str(exc)[:200]))
    return verdicts


def small_scenes() -> dict:
    """The shipped scenes at one particle per cell that then hold fewer than RUN_PARTICLES."""
    out = {}
    for path in INPUTS:
        raw = tomllib.loads(path.read_text())
        raw["simulation"]["particles_per_cell"] = 1
        for body in raw.get("bodies", []):  # the mutated copy is written elsewhere
            if "file" in body:
                body["file"] = str((path.parent / body["file"]).resolve())
        try:
            scene = parse_scene(tomli_w.dumps(raw), str(path), base_dir=path.parent)
            if sum(estimate_body_counts(scene)[0]) < RUN_PARTICLES:
                out[path] = raw
        except HpcmpmError:
            continue
    return out


def run(scenes, rng, count: int, seconds: float, alarm: int, failures: dict) -> dict:
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.simulation import Simulation

    def ring(*_):
        raise Alarm(f"the run took more than {alarm} s")

    signal.signal(signal.SIGALRM, ring)
    verdicts: dict = {}
    start = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="fuzz_scenes_"))
    try:
        i = 0
        while sum(verdicts.values()) < count and time.monotonic() - start < seconds:
            i += 1
            path = rng.choice(list(scenes))
            raw, change = mutate(scenes[path], rng)
            try:
                text = tomli_w.dumps(raw)
                validate_report(parse_scene(text, str(path), base_dir=work))
            except Exception:  # noqa: BLE001 - a verdict (or the validate mode's failure)
                continue
            scene_file = work / path.name
            out = work / f"run_{i}"
            with cli.floating_point_errors_logged():
                try:
                    signal.alarm(alarm)  # the start-up too: it counts every lattice point
                    scene_file.write_text(text)
                    scene = load_scene(str(scene_file), [])
                    sim = Simulation(scene, make_domain(scene))
                    initial_particles(sim)
                    dt = float(sim.stable_dt())
                    end = min(scene.end_time, RUN_STEPS * dt) if 0.0 < dt < math.inf else \
                        scene.end_time
                    with contextlib.redirect_stderr(io.StringIO()), \
                            contextlib.redirect_stdout(io.StringIO()):
                        code = cli.main(["run", str(scene_file), "--out", str(out), "--force",
                                         "--quiet", "--end-time", repr(end)])
                    signal.alarm(0)
                    verdicts[code] = verdicts.get(code, 0) + 1
                    if code not in VERDICTS:
                        failures.setdefault(("exit code", code), (path, [change], ""))
                except HpcmpmError:
                    signal.alarm(0)
                    verdicts["error before the run"] = verdicts.get("error before the run", 0) + 1
                except BaseException as exc:  # noqa: BLE001 - the alarm and anything unexpected
                    signal.alarm(0)
                    if isinstance(exc, KeyboardInterrupt):
                        raise
                    failures.setdefault(where(exc), (path, [change], str(exc)[:200]))
                finally:
                    scene_file.unlink(missing_ok=True)
                    shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return verdicts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("validate", "run"))
    parser.add_argument("--count", type=int, default=10_000,
                        help="validate: mutated scenes; run: runs (of the ones that validate)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--depth", type=int, default=1, help="validate: mutations per scene")
    parser.add_argument("--seconds", type=float, default=math.inf, help="run: time budget")
    parser.add_argument("--alarm", type=int, default=90, help="run: seconds a run may take")
    parser.add_argument("--scenes", nargs="*", help="scene names (default: all that fit)")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    if args.mode == "validate":
        scenes = {p: tomllib.loads(p.read_text()) for p in INPUTS}
    else:
        scenes = small_scenes()
    if args.scenes:
        scenes = {p: raw for p, raw in scenes.items() if p.stem in args.scenes}
    failures: dict = {}
    started = time.monotonic()
    if args.mode == "validate":
        verdicts = validate(scenes, rng, args.count, args.depth, failures)
    else:
        verdicts = run(scenes, rng, args.count, args.seconds, args.alarm, failures)
    print(f"{args.mode}: {sum(verdicts.values())} verdicts in "
          f"{time.monotonic() - started:.0f} s: {verdicts}; {len(failures)} failure(s)")
    for key, (path, changes, message) in failures.items():
        print(f"FAILURE {key}: {path}: {'; '.join(changes)}: {message}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

"""Random mutations of the scenes in ``inputs/`` (wrong types, signs, huge and tiny values, NaN,
infinities, missing and extra keys) through what ``hpcmpm validate`` runs: every value,
however absurd, gets a verdict (a valid scene, or one line per problem naming the file and a
key), never a traceback.

In-process and seeded (`parse_scene` plus `startup.validate_report`, what ``hpcmpm validate``
runs), so it is fast and a failure names the mutation that caused it."""

from __future__ import annotations

import copy
import math
import random
import tomllib
import warnings
from pathlib import Path

import pytest
import tomli_w

from hpcmpm.errors import SceneError
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.startup import validate_report

INPUTS = sorted(Path("inputs").glob("*.toml"))
SEED = 20261130
# 2000 take about 4 s; the 300 of before never drew the horizon, radius and axis mutations
# that broke validate (each found in a campaign of 60 000).
N_MUTATIONS = 2000

# Values a scene author (or a typo) could put anywhere.
ODD_VALUES = ["abc", "", True, False, 0, -1, 1, 2, 3, 10**20, -(10**20), 2**63, 0.0, -0.0, -1.5,
              1e-320, 1e-300, 1e308, -1e308, 1e20, math.nan, math.inf, -math.inf, [], [1.0],
              [1.0, 2.0, 3.0, 4.0], ["a", "b"], {}, {"x": 1}, [[1.0, 2.0]]]


def leaves(node, path=()):
    """Every (path, value) of a TOML tree, tables and arrays included."""
    yield path, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from leaves(value, path + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from leaves(value, path + (i,))


def mutate(raw: dict, rng: random.Random) -> tuple[dict, str]:
    """One random change of a copy of ``raw`` and a description of it."""
    raw = copy.deepcopy(raw)
    path, value = rng.choice([pv for pv in leaves(raw) if pv[0]])
    parent = raw
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    where = ".".join(str(p) for p in path)
    kind = rng.choice(["replace", "replace", "replace", "scale", "negate", "delete", "extra"])
    if kind == "scale" and isinstance(value, (int, float)) and not isinstance(value, bool):
        factor = rng.choice([1e-300, 1e-9, 1e3, 1e9, 1e300])
        new = value * factor if isinstance(value, float) else value * int(min(factor, 1e18) or 1)
        parent[last] = new
        return raw, f"{where} *= {factor:g} -> {new!r}"
    if kind == "negate" and isinstance(value, (int, float)) and not isinstance(value, bool):
        parent[last] = -value
        return raw, f"{where} = {-value!r}"
    if kind == "delete":
        del parent[last]
        return raw, f"del {where}"
    if kind == "extra" and isinstance(value, dict):
        value["bogus_key"] = rng.choice(ODD_VALUES)
        return raw, f"{where}.bogus_key added"
    new = rng.choice(ODD_VALUES)
    parent[last] = copy.deepcopy(new)
    return raw, f"{where} = {new!r}"


def verdict(path: Path, text: str) -> str:
    """"ok" or "rejected": the scene ``text`` of ``path`` through what ``hpcmpm validate``
    runs. An AssertionError says what is wrong with the verdict (a report that is not "ok", a
    problem line that does not name the file or holds a newline); any other exception is a
    bug, and so is a RuntimeWarning, a NaN or an overflow on its way to a confusing line (an
    axis whose length underflowed gave a body "outside the domain" with NaN bounds)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            report = validate_report(parse_scene(text, str(path), base_dir=path.parent))
        except SceneError as exc:
            assert exc.problems, "no problem lines"
            for line in exc.problems:
                assert line.startswith(f"{path}: ") and "\n" not in line, line
            return "rejected"
    assert report.startswith(f"{path}: ok ("), report
    return "ok"


def test_every_mutation_gets_a_one_line_verdict():
    rng = random.Random(SEED)
    scenes = {path: tomllib.loads(path.read_text()) for path in INPUTS}
    verdicts = {"ok": 0, "rejected": 0}
    for _ in range(N_MUTATIONS):
        path = rng.choice(INPUTS)
        raw, change = mutate(scenes[path], rng)
        try:
            verdicts[verdict(path, tomli_w.dumps(raw))] += 1
        except Exception as exc:  # noqa: BLE001 - the point: anything else is a bug
            pytest.fail(f"{path}: {change}: {type(exc).__name__}: {exc}")
    # Both outcomes occur, so the mutations neither all miss nor all break the scenes.
    assert verdicts["ok"] > 10 and verdicts["rejected"] > 10, verdicts


# The mutations that crashed `hpcmpm validate` before (issue 14), with the line each must give.
CRASHERS = {
    "simulation.dx=1e308": "simulation.dx: must not exceed the smallest domain extent 1",
    "simulation.dx=1e-320": "simulation.dx: gives inf cells along an axis",
    "simulation.particles_per_cell=100000000000000000000":
        "simulation.particles_per_cell: bodies[0] would take",
    "simulation.domain.lower=[-1e308, 0.0];simulation.domain.upper=[1e308, 1.0]":
        "simulation.domain: extent upper - lower overflows",
    "simulation.domain.lower=[-1e308, 0.0]": "simulation.dx: gives inf cells along an axis",
}


@pytest.mark.parametrize("override", CRASHERS)
def test_former_crashers_get_their_line(override):
    with pytest.raises(SceneError) as info:
        validate_report(load_scene("inputs/disks_2d.toml", override.split(";")))
    assert all("\n" not in line for line in info.value.problems)
    assert any(line.startswith(f"inputs/disks_2d.toml: {CRASHERS[override]}")
               for line in info.value.problems), info.value.problems


def test_a_scene_too_big_for_the_machine_gets_a_verdict_not_an_allocation():
    # 20000 particles per cell per axis: ~1e11 particles, terabytes. Counted and estimated,
    # never allocated: validate says so in a line (exit 0 with the verdict; `run` refuses).
    report = validate_report(load_scene("inputs/disks_2d.toml",
                                        ["simulation.particles_per_cell=20000"]))
    lines = report.splitlines()
    assert lines[0].startswith("inputs/disks_2d.toml: ok (about ")
    assert lines[1].startswith("inputs/disks_2d.toml: simulation.particles_per_cell: the scene "
                               "needs about")

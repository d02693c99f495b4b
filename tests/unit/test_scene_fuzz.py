"""Random mutations of the scenes in ``inputs/`` (wrong types, signs, huge and tiny values, NaN,
infinities, missing and extra keys) through what ``hpcmpm validate`` runs: every value,
however absurd, gets a verdict (a valid scene, or one line per problem naming the file and a
key), never a traceback.

In-process and seeded (`parse_scene` plus `sample_scene`, the validate path), so it is fast and
a failure names the mutation that caused it."""

from __future__ import annotations

import copy
import math
import random
import tomllib
from pathlib import Path

import pytest
import tomli_w

from hpcmpm import geometry
from hpcmpm.errors import SceneError
from hpcmpm.scene import parse_scene

INPUTS = sorted(Path("inputs").glob("*.toml"))
SEED = 20261130
N_MUTATIONS = 300

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


@pytest.fixture
def small_memory(monkeypatch):
    # The verdict "too many particles for this machine" must come before anything is allocated;
    # a 256 MiB budget exercises that path without letting a mutation fill the shared machine.
    monkeypatch.setattr(geometry, "sampling_memory_limit", lambda: 256 * 2**20)


def test_every_mutation_gets_a_one_line_verdict(small_memory):
    rng = random.Random(SEED)
    scenes = {path: tomllib.loads(path.read_text()) for path in INPUTS}
    verdicts = {"ok": 0, "rejected": 0}
    for _ in range(N_MUTATIONS):
        path = rng.choice(INPUTS)
        raw, change = mutate(scenes[path], rng)
        text = tomli_w.dumps(raw)
        try:
            scene = parse_scene(text, str(path), base_dir=path.parent)
            geometry.sample_scene(scene)
            verdicts["ok"] += 1
        except SceneError as exc:
            assert exc.problems, change
            for line in exc.problems:
                assert line.startswith(f"{path}: ") and "\n" not in line, (change, line)
            verdicts["rejected"] += 1
        except Exception as exc:  # noqa: BLE001 - the point: anything else is a bug
            pytest.fail(f"{path}: {change}: {type(exc).__name__}: {exc}")
    # Both outcomes occur, so the mutations neither all miss nor all break the scenes.
    assert verdicts["ok"] > 10 and verdicts["rejected"] > 10, verdicts


# The mutations that crashed `hpcmpm validate` before (issue 14), with the line each must give.
CRASHERS = {
    "simulation.dx=1e308": "simulation.dx: must not exceed the smallest domain extent 1",
    "simulation.dx=1e-320": "simulation.dx: gives inf cells along an axis",
    "simulation.particles_per_cell=100000000000000000000":
        "simulation.particles_per_cell: sampling the bodies would take about",
    "simulation.particles_per_cell=2000":
        "simulation.particles_per_cell: sampling the bodies would take about",
    "simulation.domain.lower=[-1e308, 0.0];simulation.domain.upper=[1e308, 1.0]":
        "simulation.domain: extent upper - lower overflows",
    "simulation.domain.lower=[-1e308, 0.0]": "simulation.dx: gives inf cells along an axis",
}


@pytest.mark.parametrize("override", CRASHERS)
def test_former_crashers_get_their_line(small_memory, override):
    from hpcmpm.scene import load_scene

    with pytest.raises(SceneError) as info:
        geometry.sample_scene(load_scene("inputs/disks_2d.toml", override.split(";")))
    assert info.value.problems == [l for l in info.value.problems if "\n" not in l]
    assert any(l.startswith(f"inputs/disks_2d.toml: {CRASHERS[override]}")
               for l in info.value.problems), info.value.problems

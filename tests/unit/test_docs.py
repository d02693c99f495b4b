"""The documentation stays true to the code it describes (each check is a drift that happened):
the README lists every exit code, docs/scene-format.md counts the scenes in inputs/, the project
cites no file outside the repository, comments name files that exist, and docs/ARCHITECTURE.md
shows the current signatures of FrameWriter and rebalance."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
UNITS = ("zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen "
         "fifteen sixteen seventeen eighteen nineteen").split()
TENS = "_ _ twenty thirty forty fifty sixty seventy eighty ninety".split()


def in_words(n: int) -> str:
    """0-99 as docs/scene-format.md spells it ("twenty-five")."""
    if n < 20:
        return UNITS[n]
    return TENS[n // 10] + ("" if n % 10 == 0 else "-" + UNITS[n % 10])


def exit_codes() -> set[int]:
    import hpcmpm.io.info
    import hpcmpm.jobs
    import hpcmpm.runner  # noqa: F401 - defines CheckpointedOnSignal
    import hpcmpm.viz.series  # noqa: F401 - defines RenderError
    from hpcmpm.errors import HpcmpmError

    found, todo = set(), [HpcmpmError]
    while todo:
        cls = todo.pop()
        found.add(cls.exit_code)
        todo.extend(cls.__subclasses__())
    return found - {1}  # the base class's code is never raised as such


def test_readme_lists_every_exit_code():
    text = (ROOT / "README.md").read_text()
    paragraph = text[text.index("Exit codes:"):].split("\n\n")[0]
    listed = {int(n) for n in re.findall(r"(?:^|[\s,:])(\d+) ", paragraph)}
    assert exit_codes() <= listed, (exit_codes() - listed, paragraph)


def test_scene_format_counts_the_scenes():
    n = len(list((ROOT / "inputs").glob("*.toml")))
    assert f"The {in_words(n)} scenes in `inputs/`" in (ROOT / "docs/scene-format.md").read_text()


def test_no_file_cites_notes_outside_the_repository():
    for path in [*ROOT.glob("scripts/*"), *ROOT.glob("docs/*.md"), *ROOT.glob("hpcmpm/**/*.py"),
                 ROOT / "README.md"]:
        if path.is_file():
            assert "shared/notes" not in path.read_text(), path


def test_errors_names_the_job_templates_that_exist():
    text = (ROOT / "hpcmpm/errors.py").read_text()
    for pattern in re.findall(r"jobs/\*[\w.]+", text):
        assert list(ROOT.glob(pattern)), pattern


def test_architecture_shows_current_signatures():
    from hpcmpm.io.frames import FrameWriter
    from hpcmpm.parallel.domain import Domain

    text = (ROOT / "docs/ARCHITECTURE.md").read_text()
    for cls, method in ((FrameWriter, "__init__"), (FrameWriter, "write"),
                        (Domain, "rebalance")):
        params = [p for p in inspect.signature(getattr(cls, method)).parameters if p != "self"]
        name = cls.__name__ if method == "__init__" else method
        shown = re.search(rf"`?{name}\(([^)]*)\)", text.replace("\n", " "))
        assert shown, name
        assert [a.split("=")[0].strip() for a in shown.group(1).split(",")] == params, \
            (name, shown.group(1), params)


def test_scene_format_documents_every_key():
    """Every key the scene check accepts and every material parameter appears in
    docs/scene-format.md (`flow_update` of herschel_bulkley and von_mises was accepted,
    defaulted and changed the physics, with no line there). Scene keys: the tables of
    scene.py and the literal key lists of its ``c.keys`` checks; documented as `key`, as
    ``key =`` in an example, or as a ``[key]`` table header. Material parameters: as `key`,
    which is how the key tables write them."""
    import hpcmpm.scene as scene
    from hpcmpm.materials import MATERIALS
    from hpcmpm.materials.failure import SHARED_KEYS
    from hpcmpm.materials.params import MATERIAL_TABLE_KEYS

    doc = (ROOT / "docs" / "scene-format.md").read_text()
    source = (ROOT / "hpcmpm" / "scene.py").read_text()
    keys = set(scene.SIMULATION_KEYS) | set(scene.COMMON_BODY_KEYS) | set(scene.TOP_KEYS)
    for table in (scene.BODY_KEYS, scene.COLLIDER_KEYS):
        for names in table.values():
            keys |= set(names)
    for call in re.finditer(r"c\.keys\(([^)]*)\)", source):
        keys |= set(re.findall(r'"([a-z_0-9]+)"', call.group(1)))
    assert len(keys) > 60

    def documented(key):
        return (f"`{key}`" in doc or f"[{key}]" in doc
                or re.search(rf"(^|[{{,]\s*){key}\s*=", doc, re.M) is not None)

    assert sorted(k for k in keys if not documented(k)) == []
    missing = {name: [k for k in cls.parameters if f"`{k}`" not in doc]
               for name, cls in MATERIALS.items()}
    for name, cls in MATERIALS.items():         # sub-tables: eos, hardening, failure
        for key, param in cls.parameters.items():
            missing[f"{name}.{key}"] = [k for k in (param.schema or ()) if not documented(k)]
    missing["(every material)"] = [k for k in MATERIAL_TABLE_KEYS + tuple(SHARED_KEYS)
                                   if f"`{k}`" not in doc]
    assert {name: keys for name, keys in missing.items() if keys} == {}


def test_readme_names_every_command_line_option():
    """Each subcommand and each of its long options appears in README.md (`hpcmpm
    jobscript`'s --activate and --output had no word there)."""
    import argparse

    from hpcmpm.cli import build_parser

    readme = (ROOT / "README.md").read_text()
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(sub.choices) >= 7
    missing = []
    for name, command in sub.choices.items():
        if f"hpcmpm {name}" not in readme:
            missing.append(name)
        for action in command._actions:
            missing += [f"{name} {o}" for o in action.option_strings
                        if o.startswith("--") and o != "--help" and o not in readme]
    assert missing == []


def test_output_md_names_every_particle_field():
    """Every particle field a scene can hold (core, deformation, material and SPB fields,
    `C`, `tau`), which `output.fields` may name, appears in docs/output.md."""
    from hpcmpm.materials import MATERIALS
    from hpcmpm.materials.failure import SPB_FIELDS
    from hpcmpm.simulation import particle_field_specs
    from hpcmpm.state import CORE_FIELDS, DEFORMATION_FIELDS

    doc = (ROOT / "docs" / "output.md").read_text()
    # The scene-level fields as a run declares them (C with MLS, prescribed with sets), the
    # fe plasticities' per-instance F_E fields, and tau (computed for output).
    names = set(CORE_FIELDS) | set(DEFORMATION_FIELDS) | set(SPB_FIELDS) | {
        "tau", "Fe", "Fe_prev"}
    names |= set(particle_field_specs(list(MATERIALS.values()), "F", "mls", True))
    assert len(names) > 25
    assert sorted(n for n in names if f"`{n}`" not in doc) == []

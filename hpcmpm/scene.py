"""TOML scene -> frozen dataclasses. All validation and its messages live here.

Every problem found is reported, one line each, as ``"{file}: {key.path}: {what is wrong}"``;
`SceneError` carries the list. `docs/scene-format.md` documents every key.
"""

from __future__ import annotations

import difflib
import math
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import tomli_w

from .errors import SceneError

KERNELS = ("quadratic", "cubic")
TRANSFERS = ("pic", "flip", "apic", "mls")
CONDITIONS = ("sticky", "slip", "separate")
BODY_SHAPES = ("box", "sphere", "cylinder", "mesh")
COLLIDER_SHAPES = ("half_space", "sphere", "box", "cylinder")
FACE_NAMES = ("x_lower", "x_upper", "y_lower", "y_upper", "z_lower", "z_upper")
AXIS_NAMES = ("x", "y", "z")


@dataclass(frozen=True)
class OutputSpec:
    every: float
    fields: tuple[str, ...] = ()
    checkpoint_every: int | None = None
    checkpoint_keep: int = 2


@dataclass(frozen=True)
class ParallelSpec:
    rebalance_threshold: float = 1.2
    rebalance_every: int = 20


@dataclass(frozen=True)
class SolverSpec:
    """The semi-implicit solve (000 §3.4, §5.5): one Newton step or Newton to convergence,
    matrix-free CG with a Jacobi or no preconditioner."""

    mode: str = "linearized"
    preconditioner: str = "jacobi"
    tolerance: float = 1e-6
    max_iterations: int = 1000
    newton_tolerance: float = 1e-6
    newton_stop: str = "momentum"


@dataclass(frozen=True)
class MaterialSpec:
    name: str
    type: str
    density: float
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BodySpec:
    name: str
    material: str
    shape: str
    params: dict
    velocity: tuple
    angular_velocity: Any
    jitter: float = 0.0
    seed: int = 0
    velocity_field: dict | None = None


@dataclass(frozen=True)
class WallFace:
    condition: str = "slip"
    friction: float = 0.0


@dataclass(frozen=True)
class WallsSpec:
    faces: tuple[WallFace, ...]


@dataclass(frozen=True)
class ColliderSpec:
    name: str
    shape: str
    params: dict
    condition: str = "sticky"
    friction: float = 0.0
    velocity: tuple = ()
    angular_velocity: Any = None
    start: float = 0.0
    end: float = math.inf


@dataclass(frozen=True)
class PrescribedSpec:
    name: str
    region: dict
    velocity: tuple
    angular_velocity: Any
    center: tuple | None = None


@dataclass(frozen=True)
class Scene:
    # ``path`` is where the text came from, not part of the scene: a scene parsed back from
    # its own ``text`` (a checkpoint's copy) compares equal to the original.
    path: str = field(compare=False)
    text: str
    dim: int
    domain_lo: tuple
    domain_hi: tuple
    dx: float
    particles_per_cell: int
    kernel: str
    transfer: str
    flip_alpha: float
    cfl: float
    dt: float | None
    max_dt: float | None
    end_time: float
    gravity: tuple
    output: OutputSpec
    materials: tuple[MaterialSpec, ...]
    bodies: tuple[BodySpec, ...]
    walls: WallsSpec
    colliders: tuple[ColliderSpec, ...]
    prescribed: tuple[PrescribedSpec, ...]
    parallel: ParallelSpec
    integrator: str = "explicit"
    solver: SolverSpec = SolverSpec()
    # Periodic axes as sorted indices (0 = x): particles leaving through one face re-enter
    # through the other, the grid wraps, the walls of those faces do not act.
    periodic: tuple[int, ...] = ()
    # "increment": each step's change of the stored J of the models that carry it becomes
    # its grid average (hpcmpm/kernels/volume.py); "none": each particle keeps its own.
    volume_averaging: str = "none"

    def material_index(self, name: str) -> int:
        return [m.name for m in self.materials].index(name)

    def periods(self) -> list[tuple[int, float]]:
        """(axis, period) of each periodic axis (`axis_periods`)."""
        return axis_periods(self.periodic, self.domain_lo, self.domain_hi)


def axis_periods(periodic, lo, hi) -> list[tuple[int, float]]:
    """(axis, period) of each of the ``periodic`` axes of the domain [lo, hi); none while lo
    or hi is unknown (a [simulation] table whose domain failed its check)."""
    if lo is None or hi is None:
        return []
    return [(a, float(hi[a] - lo[a])) for a in periodic or ()]


# -- the checker ------------------------------------------------------------------------------
class Checker:
    """Collects problems while reading values out of the raw TOML tables."""

    def __init__(self, file: str):
        self.file = file
        self.problems: list[str] = []
        self.origins: dict[str, str] = {}     # path -> the --set item that gave its value

    def problem(self, path: str, message: str) -> None:
        origin = self.origins.get(path)
        source = f" (from --set {origin})" if origin else ""
        self.problems.append(f"{self.file}: {path}: {message}{source}")

    def keys(self, table: dict, path: str, allowed: Sequence[str]) -> None:
        for key in table:
            if key not in allowed:
                close = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
                hint = f" (did you mean {close[0]!r}?)" if close else \
                    f" (allowed: {', '.join(allowed)})"
                self.problem(_join(path, key), f"unknown key{hint}")

    def table(self, parent: dict, key: str, path: str, required: bool = False) -> dict:
        value = parent.get(key)
        if value is None:
            if required:
                self.problem(_join(path, key), "missing (a table is required)")
            return {}
        if not isinstance(value, dict):
            self.problem(_join(path, key), f"must be a table, got {_describe(value)}")
            return {}
        return value

    def tables(self, parent: dict, key: str, path: str) -> list[dict]:
        value = parent.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            self.problem(_join(path, key), f"must be an array of tables ([[{key}]]), "
                                           f"got {_describe(value)}")
            return []
        return value

    def number(self, table: dict, key: str, path: str, default: Any = ..., low=None,
               high=None, low_open=True, high_open=False, integer=False, finite=False):
        """A number within the bounds. Without an upper bound +inf passes (an end time, a
        relaxation time) unless ``finite`` (a size: an infinite radius made NaN bounds)."""
        where = _join(path, key)
        if key not in table:
            if default is ...:
                self.problem(where, "missing")
                return None
            return default
        value = table[key]
        kind = "an integer" if integer else "a number"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (integer and not isinstance(value, int)):
            self.problem(where, f"must be {kind}, got {_describe(value)}")
            return None
        if not integer and not math.isfinite(value) and \
                not (value == math.inf and high is None and not finite):
            self.problem(where, f"must be finite, got {value}")
            return None
        if low is not None and (value <= low if low_open else value < low):
            self.problem(where, f"must be {'>' if low_open else '>='} {low}, got {value}")
            return None
        if high is not None and (value >= high if high_open else value > high):
            self.problem(where, f"must be {'<' if high_open else '<='} {high}, got {value}")
            return None
        return int(value) if integer else float(value)

    def string(self, table: dict, key: str, path: str, default: Any = ...,
               choices: Sequence[str] | None = None):
        where = _join(path, key)
        if key not in table:
            if default is ...:
                self.problem(where, "missing")
                return None
            return default
        value = table[key]
        if not isinstance(value, str):
            self.problem(where, f"must be a string, got {_describe(value)}")
            return None
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, list(choices), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            self.problem(where, f"unknown value {value!r} ({hint}valid: {', '.join(choices)})")
            return None
        return value

    def vector(self, table: dict, key: str, path: str, dim: int, default: Any = ...,
               positive: bool = False):
        where = _join(path, key)
        if key not in table:
            if default is ...:
                self.problem(where, "missing")
                return None
            return default
        value = table[key]
        if not isinstance(value, list) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            self.problem(where, f"must be an array of {dim} numbers, got {_describe(value)}")
            return None
        if len(value) != dim:
            self.problem(where, f"must have {dim} components (dim = {dim}), got {len(value)}")
            return None
        if not all(math.isfinite(v) for v in value):
            self.problem(where, f"must be finite, got {value}")
            return None
        if positive and any(v <= 0 for v in value):
            self.problem(where, f"components must be > 0, got {value}")
            return None
        return tuple(float(v) for v in value)

    def direction(self, table: dict, key: str, path: str, dim: int):
        """A nonzero vector, returned as the unit vector along it. Scaled by its largest
        component first: the squared length of [1e-170, 0, 0] underflows to 0 and that of
        [1e200, 0, 0] overflows, and either gave a NaN axis (a cylinder body then sampled
        nothing and was reported "outside the domain" with NaN bounds, or ignored its
        length)."""
        value = self.vector(table, key, path, dim)
        if value is None:
            return None
        unit = unit_vector(value)
        if unit is None:
            self.problem(_join(path, key), "must be a nonzero vector")
        return unit

    def angular(self, table: dict, key: str, path: str, dim: int):
        """2D: a scalar (about z); 3D: a 3-vector."""
        if key not in table:
            return 0.0 if dim == 2 else (0.0, 0.0, 0.0)
        if dim == 2:
            return self.number(table, key, path)
        return self.vector(table, key, path, 3)


def unit_vector(values) -> tuple[float, ...] | None:
    """The unit vector along finite ``values``, None for the zero vector. Scaled by the
    largest component first, so any representable direction has one: |v|^2 underflows for
    [1e-170, 0, 0] and overflows for [1e200, 0, 0]."""
    largest = max(abs(float(v)) for v in values)
    if largest == 0.0:
        return None
    scaled = [float(v) / largest for v in values]
    length = math.sqrt(sum(v * v for v in scaled))
    return tuple(v / length for v in scaled)


class CommandLineChecker(Checker):
    """The scene's checks for values given as command-line options: the same bounds and words,
    the option in place of the file and key (``--end-time: must be > 0.0, got -1.0``)."""

    def __init__(self):
        super().__init__("command line")

    def problem(self, path: str, message: str) -> None:
        self.problems.append(f"{path}: {message}")

    def option(self, name: str, value, **bounds):
        """``value`` of option ``name`` checked like a scene number (None: not given)."""
        if value is None:
            return None
        return self.number({name: value}, name, "", **bounds)

    def raise_problems(self) -> None:
        if self.problems:
            raise SceneError(self.problems)


def _join(path: str, key) -> str:
    return f"{path}.{key}" if path else str(key)


def _describe(value: Any) -> str:
    if isinstance(value, str):
        return f"string {value!r}"
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"an array {value!r}" if len(repr(value)) < 40 else "an array"
    return f"{type(value).__name__} {value!r}"


# -- overrides --------------------------------------------------------------------------------
def apply_overrides(raw: dict, overrides: Sequence[str], file: str,
                    origins: dict[str, str] | None = None) -> list[str]:
    """Apply ``key.path=value`` strings in place; returns problems. ``origins`` gets, for
    each value set, its path as the Checker writes it (``materials[0].E``) -> the ``--set``
    item, so that a problem with that value names the command line, not only the file."""
    problems = []
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            problems.append(f"{file}: --set {item}: expected key.path=value")
            continue
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        parts = key.split(".")
        node: Any = raw
        problem = None
        where = ""
        for depth, part in enumerate(parts[:-1]):
            if isinstance(node, list):
                index, problem = _entry_index(node, part, parts[depth - 1] if depth else "")
                if problem:
                    break
                node = node[index]
                where += f"[{index}]"
            elif isinstance(node, dict):
                # A section written as [[...]] that the file lacks is an empty array: its
                # entry is then "no entry 0 (colliders has 0)", not a table made up here.
                empty = [] if depth == 0 and part in ARRAY_SECTIONS else {}
                node = node.setdefault(part, empty)
                where += f".{part}" if where else part
            else:
                problem = "no such key"
                break
        last = parts[-1]
        if problem is None and isinstance(node, list):
            index, problem = _entry_index(node, last, parts[-2] if len(parts) > 1 else "")
            if problem is None:
                node[index] = value
                where += f"[{index}]"
        elif problem is None and isinstance(node, dict):
            node[last] = value
            where += f".{last}" if where else last
        elif problem is None:
            problem = "no such key"
        if problem:
            problems.append(f"{file}: --set {key}: {problem}")
        elif origins is not None:
            origins[where] = item
    return problems


# The top-level sections written as arrays of tables ([[bodies]]).
ARRAY_SECTIONS = ("materials", "bodies", "colliders", "prescribed")
# The name an array entry gets when it has none (the sections' own defaults, e.g. "body0").
DEFAULT_ENTRY_NAMES = {"bodies": "body", "colliders": "collider", "prescribed": "prescribed"}


def _entry_index(entries: list, part: str, section: str) -> tuple[int, str | None]:
    """Index of an array-of-tables entry named by ``part``: its position (``bodies.0``) or its
    ``name`` (``materials.rubber``, ``bodies.body1`` for an unnamed second body)."""
    if part.isdigit():
        if int(part) < len(entries):
            return int(part), None
        return 0, f"no entry {part} ({section} has {len(entries)})"
    names = [e.get("name", f"{DEFAULT_ENTRY_NAMES.get(section, section)}{i}")
             if isinstance(e, dict) else None for i, e in enumerate(entries)]
    if part in names:
        return names.index(part), None
    if not entries:
        return 0, f"no entry named {part!r} ({section} has 0)"
    known = ", ".join(str(n) for n in names if n is not None)
    return 0, f"no entry named {part!r} in {section} (names: {known}; or give an index)"


# -- sections ---------------------------------------------------------------------------------
SIMULATION_KEYS = ("dim", "domain", "dx", "particles_per_cell", "kernel", "transfer",
                   "flip_alpha", "cfl", "dt", "max_dt", "end_time", "gravity", "integrator",
                   "periodic", "volume_averaging")
VOLUME_AVERAGING = ("none", "increment")
SOLVER_MODES = ("linearized", "newton")
PRECONDITIONERS = ("jacobi", "none")
# Newton's stop: |grad E| <= newton_tolerance |M v*| (the issue's), or relative to v*'s
# momentum less its uniform translation (`SemiImplicitIntegrator._newton_reference`).
NEWTON_STOPS = ("momentum", "galilean")


# Cell indices come from x / dx in float64: beyond 2**53 cells along an axis neighbouring
# cells are no longer distinct numbers.
MAX_CELLS_PER_AXIS = 2.0 ** 53


def _simulation(c: Checker, raw: dict) -> dict:
    sim = c.table(raw, "simulation", "", required=True)
    if not isinstance(raw.get("simulation"), dict):
        # Reported once; every key inside would repeat it. Nothing depending on dim can be
        # checked without it.
        return {"dim": None, "domain_lo": None, "domain_hi": None, "dx": None,
                "particles_per_cell": None, "kernel": None, "transfer": None,
                "flip_alpha": None, "cfl": None, "dt": None, "max_dt": None,
                "end_time": None, "gravity": None, "integrator": None,
                "periodic": (), "volume_averaging": None}
    c.keys(sim, "simulation", SIMULATION_KEYS)
    p = "simulation"
    out: dict[str, Any] = {}
    dim = sim.get("dim")
    # An int: 2.0 equals 2 but would reach `(0.0,) * dim` and every shape as a float.
    if not isinstance(dim, int) or isinstance(dim, bool) or dim not in (2, 3):
        c.problem(f"{p}.dim", "missing" if dim is None else
                  f"must be the integer 2 or 3, got {_describe(dim)}")
        dim = None
    out["dim"] = dim
    domain = c.table(sim, "domain", p, required=True)
    c.keys(domain, f"{p}.domain", ("lower", "upper"))
    lo = hi = None
    if dim and isinstance(sim.get("domain"), dict):
        lo = c.vector(domain, "lower", f"{p}.domain", dim)
        hi = c.vector(domain, "upper", f"{p}.domain", dim)
        if lo and hi and any(h <= l for l, h in zip(lo, hi)):
            c.problem(f"{p}.domain.upper", f"must exceed domain.lower in every component, "
                                           f"got lower {list(lo)}, upper {list(hi)}")
            lo = hi = None
        elif lo and hi and not all(math.isfinite(h - l) for l, h in zip(lo, hi)):
            c.problem(f"{p}.domain", f"extent upper - lower overflows a float64, got lower "
                                     f"{list(lo)}, upper {list(hi)}")
            lo = hi = None
    out["domain_lo"], out["domain_hi"] = lo, hi
    out["dx"] = c.number(sim, "dx", p, low=0.0)
    out["particles_per_cell"] = c.number(sim, "particles_per_cell", p, 2, low=1, low_open=False,
                                         integer=True)
    out["kernel"] = c.string(sim, "kernel", p, "quadratic", KERNELS)
    out["transfer"] = c.string(sim, "transfer", p, "mls", TRANSFERS)
    out["flip_alpha"] = c.number(sim, "flip_alpha", p, 0.95, low=0.0, high=1.0, low_open=False)
    out["cfl"] = c.number(sim, "cfl", p, 0.4, low=0.0, high=2.0)
    # high=inf: finite (an infinite fixed step is no step)
    out["dt"] = c.number(sim, "dt", p, None, low=0.0, high=math.inf)
    out["max_dt"] = c.number(sim, "max_dt", p, None, low=0.0)
    out["end_time"] = c.number(sim, "end_time", p, low=0.0)
    out["gravity"] = c.vector(sim, "gravity", p, dim, (0.0,) * dim) if dim else None
    out["periodic"] = _periodic(c, sim, p, dim)
    from .solvers import INTEGRATORS

    out["integrator"] = c.string(sim, "integrator", p, "explicit", tuple(INTEGRATORS))
    out["volume_averaging"] = c.string(sim, "volume_averaging", p, "none", VOLUME_AVERAGING)
    if out["dx"] and lo and hi:
        cells = [(h - l) / out["dx"] for l, h in zip(lo, hi)]
        extents = [h - l for l, h in zip(lo, hi)]
        if any(n < 1 - 1e-6 for n in cells):
            c.problem(f"{p}.dx", f"must not exceed the smallest domain extent {min(extents):g} "
                                 f"(the grid needs a cell along every axis), got {out['dx']:g}")
        elif not all(n <= MAX_CELLS_PER_AXIS for n in cells):
            c.problem(f"{p}.dx", f"gives {max(cells):.3g} cells along an axis, more than the "
                                 f"2**53 a float64 position can tell apart, got {out['dx']:g}")
        elif any(abs(n - round(n)) > 1e-6 * max(n, 1) for n in cells):
            c.problem(f"{p}.dx", f"must divide the domain size evenly, got {out['dx']} for "
                                 f"extent {[h - l for l, h in zip(lo, hi)]}")
    return out


def _periodic(c: Checker, sim: dict, p: str, dim) -> tuple[int, ...]:
    """``periodic = ["x", ...]``: a subset of the axes, each named once; sorted indices."""
    value = sim.get("periodic", [])
    where = f"{p}.periodic"
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        c.problem(where, f"must be an array of axis names, got {_describe(value)}")
        return ()
    names = AXIS_NAMES[:dim] if dim else AXIS_NAMES
    unknown = [v for v in value if v not in names]
    if unknown:
        c.problem(where, f"unknown axis {unknown[0]!r} (valid: {', '.join(names)})")
        return ()
    repeated = sorted({v for v in value if value.count(v) > 1})
    if repeated:
        c.problem(where, f"axis {repeated[0]!r} named more than once")
        return ()
    return tuple(sorted(names.index(v) for v in value))


def _check_periodic_walls(c: Checker, raw: dict, periodic: tuple[int, ...]) -> None:
    """A face of a periodic axis is no wall: setting its condition explicitly is a mistake."""
    walls = raw.get("walls")
    if not isinstance(walls, dict):
        return
    for axis in periodic:
        for side in ("lower", "upper"):
            name = f"{AXIS_NAMES[axis]}_{side}"
            if name in walls:
                c.problem(f"walls.{name}", f"axis {AXIS_NAMES[axis]!r} is periodic "
                                           f"(simulation.periodic): its faces are not walls; "
                                           f"remove walls.{name} or the axis")


# Frames a run may be asked to write (a file each). A run also shortens its steps to land on
# each frame's time: output.every = 1.6e-306 (a fuzzed scene) took 12 081 steps of that size
# and had reached t = 1.9e-302 of 8e-5 when it was stopped.
MAX_FRAMES = 100_000


def frame_count_problem(every: float, end_time: float) -> str | None:
    """Why ``end_time / every`` frames are too many, or None (an open-ended run, end_time =
    inf, writes frames until it is stopped)."""
    if not math.isfinite(end_time) or not every > 0.0:
        return None
    frames = end_time / every
    if frames <= MAX_FRAMES:
        return None
    return (f"{every:g} would write {frames:.3g} frames to t = {end_time:g}, a file each "
            f"(at most {MAX_FRAMES}): raise output.every")


def _output(c: Checker, raw: dict, end_time) -> OutputSpec:
    t = c.table(raw, "output", "")
    c.keys(t, "output", ("every", "fields", "checkpoint_every", "checkpoint_keep"))
    every = c.number(t, "every", "output", None, low=0.0)
    if every is None and end_time is not None and math.isinf(end_time):
        c.problem("output.every", "required when simulation.end_time is inf (a run that ends "
                  "only when stopped): its default, end_time, would give the frame at t = 0 "
                  "alone")
    elif every is not None and end_time is not None:
        too_many = frame_count_problem(every, end_time)
        if too_many:
            c.problem("output.every", too_many)
    fields = t.get("fields", [])
    if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
        c.problem("output.fields", f"must be an array of strings, got {_describe(fields)}")
        fields = []
    return OutputSpec(
        every=every if every is not None else (end_time or 1.0),
        fields=tuple(fields),
        checkpoint_every=c.number(t, "checkpoint_every", "output", None, low=1, low_open=False,
                                  integer=True),
        checkpoint_keep=c.number(t, "checkpoint_keep", "output", 2, low=1, low_open=False,
                                 integer=True) or 2)


def _check_with_material_instances(c: Checker, materials, materials_complete: bool, transfer,
                                   integrator, dim, volume_averaging, periods=(),
                                   spacing=None) -> None:
    """The checks that need the materials made as the run makes them: SPB-MPM's
    combinations and ``volume_averaging`` with a material whose J it averages."""
    from .materials import make_material
    from .materials.failure import failure_scene_problems
    from .simulation import deformation_mode
    from .solvers import INTEGRATORS

    if transfer is None or integrator is None or not materials_complete or not dim:
        return  # a bad material or transfer is reported already; the list would mislead
    # Instances, as the run makes them: a material may declare fields by its parameters (J2:
    # s_zz in 2D only, T with a specific heat); a parameter combination its constructor
    # refuses is reported here, in the scene's format.
    instances = []
    for i, m in enumerate(materials):
        try:
            instances.append(make_material(m, dim))
        except SceneError as exc:
            for problem in exc.problems:
                c.problem(f"materials[{i}]", problem)
    if len(instances) < len(materials):
        return
    # SPB-MPM: combinations it cannot run (the transfer, the integrator, shared keys).
    for key, what in failure_scene_problems(instances, transfer, integrator, periods, spacing):
        c.problem(key, what)
    mode = deformation_mode(instances, INTEGRATORS[integrator].needs_velocity_gradient)
    if volume_averaging not in (None, "none") and not any(m.on_grid and m.averages_volume(mode)
                                              for m in instances):
        c.problem("simulation.volume_averaging",
                  f"{volume_averaging!r} averages the stored J of oldroyd_b, herschel_bulkley, "
                  "von_mises and weakly_compressible (unless it carries F, beside an F-based "
                  "material with the explicit integrator); no material of this scene carries "
                  "one")



def _check_output_fields(c: Checker, scene: Scene) -> None:
    """Each requested output field exists in this scene's particles (the writer would skip it
    silently otherwise): a core field, a field the scene declares (`particle_field_specs`,
    what the run allocates, with the materials configured against the scene as the run
    configures them: a PD clamp's state depends on the walls its bodies start near), or
    ``tau``, the Kirchhoff stress computed for output. Runs with the materials' own checks
    against the scene, so validation reports both kinds of problem at once."""
    from .simulation import configured_materials, deformation_mode, particle_field_specs
    from .solvers import INTEGRATORS
    from .state import CORE_FIELDS

    try:
        instances = configured_materials(scene, scene.dim)
    except Exception as exc:  # noqa: BLE001 - re-raised unless a problem explains it
        # A material the scene checks found wrong (a missing stress material, ...) may not
        # configure: that problem is reported already.
        if c.problems:
            return
        if isinstance(exc, SceneError):
            c.problems.extend(exc.problems)
            return
        raise
    mode = deformation_mode(instances, INTEGRATORS[scene.integrator].needs_velocity_gradient)
    valid = list(CORE_FIELDS) + list(particle_field_specs(instances, mode, scene.transfer,
                                                          bool(scene.prescribed))) + ["tau"]
    output = scene.output
    for i, name in enumerate(output.fields):
        if name not in valid:
            close = difflib.get_close_matches(name, valid, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            c.problem(f"output.fields[{i}]", f"no particle field {name!r} in this scene "
                                             f"({hint}available: {', '.join(valid)})")


def _parallel(c: Checker, raw: dict) -> ParallelSpec:
    t = c.table(raw, "parallel", "")
    c.keys(t, "parallel", ("rebalance_threshold", "rebalance_every"))
    return ParallelSpec(
        rebalance_threshold=c.number(t, "rebalance_threshold", "parallel", 1.2, low=1.0) or 1.2,
        rebalance_every=c.number(t, "rebalance_every", "parallel", 20, low=1, low_open=False,
                                 integer=True) or 20)


def _solver(c: Checker, raw: dict) -> SolverSpec:
    t = c.table(raw, "solver", "")
    c.keys(t, "solver", ("mode", "preconditioner", "tolerance", "max_iterations",
                         "newton_tolerance", "newton_stop"))
    d = SolverSpec()
    values = dict(
        mode=c.string(t, "mode", "solver", d.mode, SOLVER_MODES),
        preconditioner=c.string(t, "preconditioner", "solver", d.preconditioner,
                                PRECONDITIONERS),
        tolerance=c.number(t, "tolerance", "solver", d.tolerance, low=0.0, high=1.0,
                           high_open=True),
        max_iterations=c.number(t, "max_iterations", "solver", d.max_iterations, low=1,
                                low_open=False, integer=True),
        newton_tolerance=c.number(t, "newton_tolerance", "solver", d.newton_tolerance,
                                  low=0.0, high=1.0, high_open=True),
        newton_stop=c.string(t, "newton_stop", "solver", d.newton_stop, NEWTON_STOPS))
    return SolverSpec(**{k: getattr(d, k) if v is None else v for k, v in values.items()})


def _materials(c: Checker, raw: dict) -> tuple[MaterialSpec, ...]:
    from .materials import MATERIALS, validate_params

    out = []
    entries = c.tables(raw, "materials", "")
    if not entries:
        c.problem("materials", "missing: at least one [[materials]] table is required")
    names = set()
    for i, m in enumerate(entries):
        p = f"materials[{i}]"
        name = c.string(m, "name", p)
        mtype = c.string(m, "type", p, choices=sorted(MATERIALS))
        # high=inf: finite (the Checker admits +inf only where no upper bound is given)
        density = c.number(m, "density", p, low=0.0, high=math.inf)
        if name in names:
            c.problem(f"{p}.name", f"duplicate material name {name!r}")
        names.add(name)
        params = {k: v for k, v in m.items() if k not in ("name", "type", "density")}
        problems = validate_params(mtype, params) if mtype is not None else []
        for problem in problems:
            # validate_params says "key: what is wrong" (the schema checks each value's
            # kind: number, choice, table); the key joins the TOML path.
            key, _, what = problem.partition(": ")
            c.problem(f"{p}.{key}", what)
        if None not in (name, mtype, density) and not problems:
            out.append(MaterialSpec(name, mtype, density, {
                k: float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v
                for k, v in params.items()}))
    return tuple(out)


BODY_KEYS = {
    "box": ("lower", "upper"), "sphere": ("center", "radius"),
    "cylinder": ("center", "axis", "radius", "length"),
    "mesh": ("file", "scale", "translate"),
}
COMMON_BODY_KEYS = ("name", "material", "shape", "velocity", "angular_velocity", "jitter",
                    "seed", "velocity_field")


def _bodies(c: Checker, raw: dict, dim, materials, lo, hi, base_dir: Path) -> tuple:
    out = []
    # The names the file defines, also of materials with a problem of their own (a body that
    # names a valid but badly parametrised material is not "unknown"; one naming no material
    # is reported with the rest, not after they are fixed).
    names = {m.name for m in materials} | {
        m["name"] for m in (raw.get("materials") if isinstance(raw.get("materials"), list)
                            else ()) if isinstance(m, dict) and isinstance(m.get("name"), str)}
    entries = c.tables(raw, "bodies", "")
    if not entries:
        c.problem("bodies", "missing: at least one [[bodies]] table is required")
    for i, b in enumerate(entries):
        p = f"bodies[{i}]"
        shape = c.string(b, "shape", p, choices=BODY_SHAPES)
        c.keys(b, p, COMMON_BODY_KEYS + (BODY_KEYS.get(shape, ()) if shape else
                                        tuple(k for v in BODY_KEYS.values() for k in v)))
        material = c.string(b, "material", p)
        name = c.string(b, "name", p, f"body{i}")
        if material is not None and names and material not in names:
            c.problem(f"{p}.material", f"unknown material {material!r} (defined: "
                                       f"{', '.join(sorted(names))})")
        if not dim:
            continue
        params = _body_params(c, b, p, shape, dim, base_dir)
        velocity = c.vector(b, "velocity", p, dim, (0.0,) * dim)
        angular = c.angular(b, "angular_velocity", p, dim)
        jitter = c.number(b, "jitter", p, 0.0, low=0.0, high=1.0, low_open=False)
        # >= 0: numpy's PCG64 refuses a negative seed
        seed = c.number(b, "seed", p, 0, low=0, low_open=False, integer=True)
        vfield = _velocity_field(c, b, p, dim)
        if params is not None and lo and hi:
            blo, bhi = body_bounds(shape, params, dim)
            if any(bl < l - 1e-12 for bl, l in zip(blo, lo)) or \
                    any(bh > h + 1e-12 for bh, h in zip(bhi, hi)):
                c.problem(p, f"body lies outside the domain: its bounds {_fmt(blo)}..{_fmt(bhi)}"
                             f" exceed the domain {_fmt(lo)}..{_fmt(hi)}")
        if None not in (name, shape, material, params, velocity, angular, jitter, seed):
            out.append(BodySpec(name, material, shape, params, velocity,
                                angular, jitter, seed, vfield))
    return tuple(out)


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


def _body_params(c: Checker, b: dict, p: str, shape, dim: int, base_dir: Path):
    if shape == "box":
        lower, upper = c.vector(b, "lower", p, dim), c.vector(b, "upper", p, dim)
        if lower and upper and any(u <= l for l, u in zip(lower, upper)):
            c.problem(f"{p}.upper", "must exceed lower in every component")
            return None
        return None if None in (lower, upper) else {"lower": lower, "upper": upper}
    if shape == "sphere":
        center = c.vector(b, "center", p, dim)
        radius = c.number(b, "radius", p, low=0.0, finite=True)
        return None if None in (center, radius) else {"center": center, "radius": radius}
    if shape == "cylinder":
        if dim != 3:
            c.problem(f"{p}.shape", "cylinder bodies need dim = 3 (in 2D use a box)")
            return None
        center, axis = c.vector(b, "center", p, 3), c.direction(b, "axis", p, 3)
        radius = c.number(b, "radius", p, low=0.0, finite=True)
        length = c.number(b, "length", p, low=0.0, finite=True)
        return None if None in (center, axis, radius, length) else \
            {"center": center, "axis": axis, "radius": radius, "length": length}
    if shape == "mesh":
        file = c.string(b, "file", p)
        scale = c.number(b, "scale", p, 1.0, low=0.0)
        translate = c.vector(b, "translate", p, dim, (0.0,) * dim)
        if file is None or None in (scale, translate):
            return None
        path = (base_dir / file).resolve()
        from .geometry.mesh import MeshError, load_mesh

        try:
            points, _ = load_mesh(path, dim)
        except MeshError as exc:
            c.problem(f"{p}.file", str(exc))
            return None
        params = {"file": str(path), "scale": scale, "translate": translate}
        pts = points * scale + translate
        params["bounds"] = (tuple(pts.min(axis=0)), tuple(pts.max(axis=0)))
        return params
    return None


def _velocity_field(c: Checker, b: dict, p: str, dim: int):
    if "velocity_field" not in b:
        return None
    t = c.table(b, "velocity_field", p)
    q = f"{p}.velocity_field"
    c.keys(t, q, ("type", "amplitude", "length", "axis"))
    kind = c.string(t, "type", q, choices=("axial_mode",))
    amp = c.number(t, "amplitude", q, finite=True)
    length = c.number(t, "length", q, low=0.0, finite=True)
    axis = c.number(t, "axis", q, 0, low=0, high=dim - 1, low_open=False, integer=True)
    if None in (kind, amp, length, axis):
        return None
    return {"type": kind, "amplitude": amp, "length": length, "axis": axis}


def body_bounds(shape: str, params: dict, dim: int):
    """Axis-aligned bounding box of a body."""
    if shape == "box":
        return params["lower"], params["upper"]
    if shape == "sphere":
        c, r = params["center"], params["radius"]
        return tuple(x - r for x in c), tuple(x + r for x in c)
    if shape == "cylinder":
        import numpy as np

        c = np.asarray(params["center"])
        a = np.asarray(params["axis"]) / np.linalg.norm(params["axis"])
        h, r = params["length"] / 2, params["radius"]
        ext = np.abs(a) * h + r * np.sqrt(np.clip(1 - a * a, 0, None))
        return tuple(c - ext), tuple(c + ext)
    return params["bounds"]


def _walls(c: Checker, raw: dict, dim) -> WallsSpec:
    t = c.table(raw, "walls", "")
    faces = FACE_NAMES[: 2 * dim] if dim else FACE_NAMES
    c.keys(t, "walls", ("default", "friction") + tuple(faces))
    default = c.string(t, "default", "walls", "slip", CONDITIONS) or "slip"
    friction = c.number(t, "friction", "walls", 0.0, low=0.0, low_open=False) or 0.0
    out = []
    for name in faces:
        f = c.table(t, name, "walls")
        c.keys(f, f"walls.{name}", ("condition", "friction"))
        cond = c.string(f, "condition", f"walls.{name}", default, CONDITIONS) or default
        fr = c.number(f, "friction", f"walls.{name}", friction, low=0.0, low_open=False)
        out.append(WallFace(cond, friction if fr is None else fr))
    return WallsSpec(tuple(out))


COLLIDER_KEYS = {
    "half_space": ("point", "normal"), "sphere": ("center", "radius"),
    "box": ("center", "half_extents", "rotation"),
    "cylinder": ("center", "axis", "radius", "half_length"),
}


def _colliders(c: Checker, raw: dict, dim) -> tuple:
    out = []
    for i, t in enumerate(c.tables(raw, "colliders", "")):
        p = f"colliders[{i}]"
        shape = c.string(t, "shape", p, choices=COLLIDER_SHAPES)
        name = c.string(t, "name", p, f"collider{i}")
        common = ("name", "shape", "condition", "friction", "velocity", "angular_velocity",
                  "start", "end")
        c.keys(t, p, common + COLLIDER_KEYS.get(shape, ()))
        if not dim or shape is None:
            continue
        params = {}
        if shape == "half_space":
            params = {"point": c.vector(t, "point", p, dim),
                      "normal": c.direction(t, "normal", p, dim)}
        elif shape == "sphere":
            params = {"center": c.vector(t, "center", p, dim),
                      "radius": c.number(t, "radius", p, low=0.0, finite=True)}
        elif shape == "box":
            params = {"center": c.vector(t, "center", p, dim),
                      "half_extents": c.vector(t, "half_extents", p, dim, positive=True)}
            if "rotation" in t:
                params["rotation"] = c.angular(t, "rotation", p, dim)
        else:
            if dim != 3:
                c.problem(f"{p}.shape", "cylinder colliders need dim = 3")
                continue
            params = {"center": c.vector(t, "center", p, 3),
                      "axis": c.direction(t, "axis", p, 3),
                      "radius": c.number(t, "radius", p, low=0.0, finite=True),
                      "half_length": c.number(t, "half_length", p, low=0.0, finite=True)}
        cond = c.string(t, "condition", p, "sticky", CONDITIONS)
        friction = c.number(t, "friction", p, 0.0, low=0.0, low_open=False)
        velocity = c.vector(t, "velocity", p, dim, (0.0,) * dim)
        angular = c.angular(t, "angular_velocity", p, dim)
        start = c.number(t, "start", p, 0.0, low=0.0, low_open=False)
        end = c.number(t, "end", p, math.inf, low=0.0, low_open=False)
        if None in params.values() or None in (name, cond, friction, velocity, angular, start, end):
            continue
        if end < start:
            c.problem(f"{p}.end", f"must be >= start ({start:g}), got {end:g}")
        out.append(ColliderSpec(name, shape, params, cond, friction,
                                velocity, angular, start, end))
    return tuple(out)


def collider_reach(spec: ColliderSpec) -> float:
    """The farthest a bounded collider reaches from its centre in any orientation (its
    bounding sphere): the radius of a sphere, the half-diagonal of a box, sqrt(r^2 + h^2) of
    a cylinder."""
    p = spec.params
    if spec.shape == "sphere":
        return float(p["radius"])
    if spec.shape == "box":
        return float(math.sqrt(sum(h * h for h in p["half_extents"])))
    return float(math.hypot(p["radius"], p["half_length"]))


def _check_periodic_colliders(c: Checker, colliders, periods) -> None:
    """A collider acts through its periodic images one period away (`Collider`): a bounded
    one must reach less than half a period from its centre (its images would overlap), and a
    half-space must be the same at both faces of a periodic axis (its normal perpendicular
    to the axis, and not turning). ``periods``: `axis_periods`."""
    for i, spec in enumerate(colliders):
        p = f"colliders[{i}]"
        for axis, period in periods:
            name = AXIS_NAMES[axis]
            if spec.shape == "half_space":
                normal = spec.params["normal"]
                if normal[axis] != 0.0:
                    c.problem(f"{p}.normal", f"has a component along the periodic axis "
                                             f"{name!r}: the half-space would differ at its two "
                                             f"faces; make the normal perpendicular to {name!r}")
                elif any(spec.angular_velocity) if isinstance(spec.angular_velocity, tuple) \
                        else spec.angular_velocity:
                    c.problem(f"{p}.angular_velocity", f"a turning half-space would come to "
                                                       f"differ at the two faces of the "
                                                       f"periodic axis {name!r}")
                continue
            reach = collider_reach(spec)
            if 2.0 * reach >= period:
                c.problem(p, f"reaches {reach:g} from its centre, half the period {period:g} "
                             f"of the periodic axis {name!r} or more: its periodic images "
                             f"would overlap (the domain must be wider than {2.0 * reach:g} "
                             f"along {name!r})")


def _prescribed(c: Checker, raw: dict, dim) -> tuple:
    out = []
    for i, t in enumerate(c.tables(raw, "prescribed", "")):
        p = f"prescribed[{i}]"
        c.keys(t, p, ("name", "region", "velocity", "angular_velocity", "center"))
        name = c.string(t, "name", p, f"prescribed{i}")
        if not dim:
            continue
        region = c.table(t, "region", p, required=True)
        if not isinstance(t.get("region"), dict):
            continue  # reported above; its lower/upper would only repeat it
        c.keys(region, f"{p}.region", ("lower", "upper"))
        lower = c.vector(region, "lower", f"{p}.region", dim)
        upper = c.vector(region, "upper", f"{p}.region", dim)
        if lower and upper and any(u <= l for l, u in zip(lower, upper)):
            c.problem(f"{p}.region.upper", "must exceed region.lower in every component")
            continue
        velocity = c.vector(t, "velocity", p, dim, (0.0,) * dim)
        angular = c.angular(t, "angular_velocity", p, dim)
        center = c.vector(t, "center", p, dim, None)
        if None in (name, lower, upper, velocity, angular):
            continue
        out.append(PrescribedSpec(name,
                                  {"lower": lower, "upper": upper}, velocity, angular, center))
    return tuple(out)


TOP_KEYS = ("simulation", "output", "parallel", "solver", "materials", "bodies", "walls",
            "colliders", "prescribed")


def parse_scene(text: str, path: str = "<string>", overrides: Sequence[str] = (),
                base_dir: Path | None = None) -> Scene:
    """Validate a scene given as TOML text; raises `SceneError` with every problem."""
    file = str(path)
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{file}: TOML syntax error: {exc}") from None
    c = Checker(file)
    c.problems.extend(apply_overrides(raw, overrides, file, c.origins))
    long_integers = _long_integers(raw)
    for where in long_integers:
        c.problem(where, "integer too large (beyond the range of a float64)")
    if long_integers:
        raise SceneError(c.problems)  # the checks below would fail converting it to float
    c.keys(raw, "", TOP_KEYS)
    base_dir = base_dir or (Path(path).parent if path != "<string>" else Path("."))
    sim = _simulation(c, raw)
    dim = sim["dim"]
    output = _output(c, raw, sim["end_time"])
    parallel = _parallel(c, raw)
    solver = _solver(c, raw)
    materials = _materials(c, raw)
    bodies = _bodies(c, raw, dim, materials, sim["domain_lo"], sim["domain_hi"], base_dir)
    walls = _walls(c, raw, dim)
    _check_periodic_walls(c, raw, sim["periodic"])
    colliders = _colliders(c, raw, dim)
    periods = axis_periods(sim["periodic"], sim["domain_lo"], sim["domain_hi"])
    _check_periodic_colliders(c, colliders, periods)
    prescribed = _prescribed(c, raw, dim)
    entries = raw.get("materials")
    _check_with_material_instances(c, materials,
                                   isinstance(entries, list) and len(entries) == len(materials),
                                   sim["transfer"], sim["integrator"], sim["dim"],
                                   sim["volume_averaging"], periods,
                                   sim["dx"] / sim["particles_per_cell"]
                                   if sim["dx"] and sim["particles_per_cell"] else None)
    if c.problems:
        raise SceneError(c.problems)
    _resolve_mesh_paths(raw, bodies)
    scene = Scene(path=file, text=tomli_w.dumps(raw), output=output, materials=materials,
                  bodies=bodies, walls=walls, colliders=colliders, prescribed=prescribed,
                  parallel=parallel, solver=solver, **sim)
    _check_materials_in_scene(c, scene)
    _check_output_fields(c, scene)
    if c.problems:
        raise SceneError(c.problems)
    return scene


def _long_integers(node, path: str = "") -> list[str]:
    """The paths (as the Checker writes them) of integers too large for a float64 (tomllib
    reads integers of any size; every check converts numbers to float, which would overflow);
    a number in an array is reported at the array's key."""
    if isinstance(node, dict):
        return [w for key, value in node.items() for w in _long_integers(value, _join(path, key))]
    if isinstance(node, list):
        found = [w for i, value in enumerate(node) for w in _long_integers(value, f"{path}[{i}]")]
        return [path] if found and not any(isinstance(v, (dict, list)) for v in node) else found
    if isinstance(node, int) and not isinstance(node, bool) and abs(node) > sys.float_info.max:
        return [path]
    return []


def _check_materials_in_scene(c: Checker, scene: Scene) -> None:
    """Each material's parameters against the rest of the scene (`Material.scene_problems`:
    e.g. a peridynamic horizon below the particle spacing, a pre-crack outside the domain)."""
    from .materials import MATERIALS

    for i, spec in enumerate(scene.materials):
        for problem in MATERIALS[spec.type].scene_problems(spec, scene):
            key, _, what = problem.partition(": ")
            c.problem(f"materials[{i}].{key}", what)


def _resolve_mesh_paths(raw: dict, bodies) -> None:
    """Store absolute mesh paths in the resolved text, so a checkpoint's scene still finds
    its meshes from any working directory."""
    for entry, body in zip(raw.get("bodies", []), bodies):
        if body.shape == "mesh":
            entry["file"] = body.params["file"]


def load_scene(path, overrides: Sequence[str] = ()) -> Scene:
    """Read and validate a scene file (``--set`` overrides applied first)."""
    p = Path(path)
    try:
        # TOML is UTF-8 whatever the locale says; a byte-order mark (Windows editors write
        # one) is not part of the text: tomllib called it "Invalid statement" at 1:1.
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise SceneError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: cannot read: {exc}") from None
    return parse_scene(text, str(path), overrides, base_dir=p.parent)

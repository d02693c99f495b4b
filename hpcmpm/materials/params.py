"""The parameter schema of the materials: what a ``[[materials]]`` table may hold, its checks
and the Lamé conversion.

Parameter schema
----------------
Every material class has a class attribute ``parameters: dict[str, Param]`` naming each key it
accepts in a scene's ``[[materials]]`` table (besides ``name``, ``type`` and ``density``, which
`MaterialSpec` holds itself). `Param` is a NamedTuple with the fields, in order::

    low: float             lower bound (-math.inf for none)
    high: float            upper bound (math.inf for none)
    required: bool         True: the key must be given; False: ``default`` is used
    default: float | None  value used when an optional key is absent (None when required)
    low_inclusive: bool    True: value >= low is allowed; False (default): value > low
    high_inclusive: bool   True: value <= high is allowed; False (default): value < high
    doc: str               one line for the user: meaning and units
    choices: tuple | None  the value is a string, one of these (``low``/``high`` unused)
    schema: dict | None    the value is a table checked against this nested schema
    check: callable | None the value is anything; ``check(value)`` returns a problem
                           string ("must be ...") or None

So ``Param(0.0, math.inf)`` is "required, > 0" and ``Param(-1.0, 0.5)`` is "required,
-1 < value < 0.5". A numeric value must be a real number (bool is not) and finite unless a
bound is infinite and inclusive (``Param(0.0, math.inf, high_inclusive=True)`` accepts
``inf``, e.g. an infinite relaxation time). ``choice(("a", "b"), "a")`` and
``table({...})`` build the non-numeric kinds.

`check_params(parameters, params)` returns one problem string per bad key, in the house format
``"{key}: {what is wrong}"``, e.g. ``"nu: must be < 0.5, got 0.5"``, ``"E: missing"``,
``"Eyoung: unknown key (did you mean 'E'?)"``. The scene validator prefixes the TOML path.
"""

from __future__ import annotations

import difflib
import math
from typing import Any, Callable, NamedTuple

from ..scene import _describe


class Param(NamedTuple):
    """Accepted range of one material parameter (see the module docstring)."""

    low: float
    high: float
    required: bool = True
    default: float | None = None
    low_inclusive: bool = False
    high_inclusive: bool = False
    doc: str = ""
    choices: tuple | None = None
    schema: dict | None = None
    check: Callable[[Any], str | None] | None = None


def choice(choices: tuple, default: str | None = None, doc: str = "") -> Param:
    """A string parameter, one of ``choices``; optional when a default is given."""
    return Param(-math.inf, math.inf, required=default is None, default=default, doc=doc,
                 choices=tuple(choices))


def table(schema: dict, required: bool = False, doc: str = "") -> Param:
    """A sub-table parameter (``eos = {type = ..., c0 = ...}``) checked against ``schema``;
    absent means None unless required."""
    return Param(-math.inf, math.inf, required=required, default=None, doc=doc,
                 schema=dict(schema))


YOUNG = Param(0.0, math.inf, doc="Young's modulus E (stress units)")
POISSON = Param(-1.0, 0.5, doc="Poisson ratio nu (dimensionless)")


def _number(value: Any) -> float | None:
    # A TOML integer or float only: a quoted number ("2e6") is a string, as in the scene's
    # own keys (float() would read it), and bool is not a number.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


# The keys of a [[materials]] table that the scene reads itself (scene.py) before a model's
# schema sees the rest: a misspelling of one of them is hinted like any other key.
MATERIAL_TABLE_KEYS = ("name", "type", "density")


def check_params(parameters: dict[str, Param], params: dict[str, Any],
                 also: tuple[str, ...] = ()) -> list[str]:
    """Problems with ``params`` against the schema ``parameters``: one string per missing,
    unknown, mistyped or out-of-range key; empty when all is well. Keys of sub-tables are
    reported with their path (``eos.c0: must be > 0, got -1``). ``also``: keys accepted
    where ``params`` came from but checked elsewhere (hints name them too)."""
    problems = []
    accepted = list(also) + list(parameters)
    for key in params:
        if key not in parameters:
            close = difflib.get_close_matches(key, accepted, n=1, cutoff=0.5)
            if not close:
                # Short names such as "E" score low against typos such as "Eyoung"; a
                # case-insensitive prefix is a good enough hint.
                close = [k for k in accepted
                         if key.lower().startswith(k.lower()) or k.lower().startswith(key.lower())]
            hint = f" (did you mean {close[0]!r}?)" if close else \
                f" (accepted: {', '.join(accepted) or 'none'})"
            problems.append(f"{key}: unknown key{hint}")
    for key, spec in parameters.items():
        if key not in params:
            if spec.required:
                problems.append(f"{key}: missing")
            continue
        problem = check_value(spec, params[key])
        if isinstance(problem, list):
            problems += [f"{key}.{p}" for p in problem]
        elif problem:
            problems.append(f"{key}: {problem}")
    return problems


def check_value(spec: Param, value: Any) -> str | list[str] | None:
    """What is wrong with one value (None when nothing); a sub-table gives a list."""
    if spec.check is not None:
        return spec.check(value)
    if spec.choices is not None:
        if not isinstance(value, str):
            return f"must be a string, one of {', '.join(spec.choices)}; got {_describe(value)}"
        if value not in spec.choices:
            close = difflib.get_close_matches(value, list(spec.choices), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            return f"unknown value {value!r} ({hint}valid: {', '.join(spec.choices)})"
        return None
    if spec.schema is not None:
        if not isinstance(value, dict):
            return f"must be a table ({{key = value, ...}}), got {_describe(value)}"
        return check_params(spec.schema, value) or None
    x = _number(value)
    if x is None or math.isnan(x):
        return f"must be a number, got {_describe(value)}"
    infinite_ok = (x == math.inf and spec.high == math.inf and spec.high_inclusive) or \
        (x == -math.inf and spec.low == -math.inf and spec.low_inclusive)
    if not math.isfinite(x) and not infinite_ok:
        return f"must be finite, got {x}"
    if spec.low_inclusive and x < spec.low:
        return f"must be >= {spec.low:g}, got {x:g}"
    if not spec.low_inclusive and x <= spec.low:
        return f"must be > {spec.low:g}, got {x:g}"
    if spec.high_inclusive and x > spec.high:
        return f"must be <= {spec.high:g}, got {x:g}"
    if not spec.high_inclusive and x >= spec.high:
        return f"must be < {spec.high:g}, got {x:g}"
    return None


def resolve_params(parameters: dict[str, Param], params: dict[str, Any]) -> dict[str, Any]:
    """Values with defaults filled in: numbers as float, strings as given, sub-tables
    resolved against their own schema (None when an optional table is absent)."""
    out: dict[str, Any] = {}
    for key, spec in parameters.items():
        if key not in params:
            out[key] = spec.default
        elif spec.schema is not None:
            out[key] = resolve_params(spec.schema, params[key])
        elif spec.choices is not None or spec.check is not None:
            out[key] = params[key]
        else:
            out[key] = float(params[key])
    return out


def lame(E: float, nu: float) -> tuple[float, float]:
    """(mu, lambda) from Young's modulus and Poisson ratio (3D formulas; the 2D models are
    plane strain, which uses the same Lamé parameters)."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam

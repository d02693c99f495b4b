"""The Material base class, its parameter schema, and the Lamé conversion.

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
    choices: tuple | None  a string key: the allowed values (``default`` may be one of them)
    schema: dict | None    a sub-table key (``eos = {type = ..., c0 = ...}``): its own schema
    check: callable | None extra check of the value: returns a problem string or None

So ``Param(0.0, math.inf)`` is "required, > 0" and ``Param(-1.0, 0.5)`` is "required,
-1 < value < 0.5". A numeric value must be a real number (bool is not) and finite unless a
bound is infinite and inclusive (none of the built-in models allows that). A ``choices`` key
takes a string from the tuple; a ``schema`` key takes a table checked against that schema,
its problems named ``"{key}.{subkey}: ..."`` (``"eos.c0: must be > 0, got -1"``).

`check_params(parameters, params)` returns one problem string per bad key, in the house format
``"{key}: {what is wrong}"``, e.g. ``"nu: must be < 0.5, got 0.5"``, ``"E: missing"``,
``"Eyoung: unknown key (did you mean 'E'?)"``. The scene validator prefixes the TOML path.
"""

from __future__ import annotations

import difflib
import math
from typing import Any, Callable, ClassVar, NamedTuple

import numpy as np

from ..errors import SceneError
from ..state import FieldSpec


class Param(NamedTuple):
    """Accepted range of one material parameter (see the module docstring)."""

    low: float = -math.inf
    high: float = math.inf
    required: bool = True
    default: Any = None
    low_inclusive: bool = False
    high_inclusive: bool = False
    doc: str = ""
    choices: tuple[str, ...] | None = None
    schema: dict[str, "Param"] | None = None
    check: Callable[[Any], str | None] | None = None


YOUNG = Param(0.0, math.inf, doc="Young's modulus E (stress units)")
POISSON = Param(-1.0, 0.5, doc="Poisson ratio nu (dimensionless)")


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x


def check_params(parameters: dict[str, Param], params: dict[str, Any]) -> list[str]:
    """Problems with ``params`` against the schema ``parameters``: one string per missing,
    unknown, non-numeric or out-of-range key; empty when all is well."""
    problems = []
    for key in params:
        if key not in parameters:
            close = difflib.get_close_matches(key, list(parameters), n=1, cutoff=0.5)
            if not close:
                # Short names such as "E" score low against typos such as "Eyoung"; a
                # case-insensitive prefix is a good enough hint.
                close = [k for k in parameters
                         if key.lower().startswith(k.lower()) or k.lower().startswith(key.lower())]
            hint = f" (did you mean {close[0]!r}?)" if close else \
                f" (accepted: {', '.join(parameters) or 'none'})"
            problems.append(f"{key}: unknown key{hint}")
    for key, spec in parameters.items():
        if key not in params:
            if spec.required:
                problems.append(f"{key}: missing")
            continue
        if spec.choices is not None or spec.schema is not None:
            problems += _check_non_numeric(key, spec, params[key])
            continue
        x = _number(params[key])
        if x is None or math.isnan(x):
            problems.append(f"{key}: must be a number, got {params[key]!r}")
            continue
        if not math.isfinite(x):
            problems.append(f"{key}: must be finite, got {x}")
            continue
        if spec.low_inclusive and x < spec.low:
            problems.append(f"{key}: must be >= {spec.low:g}, got {x:g}")
        elif not spec.low_inclusive and x <= spec.low:
            problems.append(f"{key}: must be > {spec.low:g}, got {x:g}")
        if spec.high_inclusive and x > spec.high:
            problems.append(f"{key}: must be <= {spec.high:g}, got {x:g}")
        elif not spec.high_inclusive and x >= spec.high:
            problems.append(f"{key}: must be < {spec.high:g}, got {x:g}")
        if spec.check is not None and (what := spec.check(x)) is not None:
            problems.append(f"{key}: {what}")
    return problems


def _check_non_numeric(key: str, spec: Param, value: Any) -> list[str]:
    """Problems of a ``choices`` (string) or ``schema`` (sub-table) key."""
    if spec.choices is not None:
        if not isinstance(value, str) or value not in spec.choices:
            return [f"{key}: must be one of {', '.join(map(repr, spec.choices))}, "
                    f"got {value!r}"]
        return []
    if not isinstance(value, dict):
        return [f"{key}: must be a table {{...}}, got {value!r}"]
    problems = [f"{key}.{p}" for p in check_params(spec.schema, value)]
    if not problems and spec.check is not None and (what := spec.check(value)) is not None:
        problems.append(f"{key}: {what}")
    return problems


def resolve_params(parameters: dict[str, Param], params: dict[str, Any]) -> dict[str, Any]:
    """The checked ``params`` with defaults filled in: numbers as float, choices as str,
    sub-tables resolved by their schema (an absent optional sub-table stays None)."""
    out: dict[str, Any] = {}
    for key, spec in parameters.items():
        if key not in params:
            out[key] = spec.default
        elif spec.schema is not None:
            out[key] = resolve_params(spec.schema, params[key])
        elif spec.choices is not None:
            out[key] = str(params[key])
        else:
            out[key] = float(params[key])
    return out


def lame(E: float, nu: float) -> tuple[float, float]:
    """(mu, lambda) from Young's modulus and Poisson ratio (3D formulas; the 2D models are
    plane strain, which uses the same Lamé parameters)."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


class Material:
    """A constitutive model: per-particle fields, stress update, energy and wave speed.

    Subclasses set ``name``, ``parameters``, ``fields``, ``uses_svd``, and the small-strain
    Lamé parameters ``self.mu``, ``self.lam`` (used by `wave_speed`), and implement
    `update_stress` and `energy` by dispatching once on ``dim`` to a 2D or 3D numba kernel.
    """

    name: ClassVar[str] = ""
    parameters: ClassVar[dict[str, Param]] = {}
    fields: ClassVar[dict[str, FieldSpec]] = {}
    uses_svd: ClassVar[bool] = False
    # True when the stress depends on J = det F alone: a scene of such materials stores J
    # instead of F (update_stress and energy then get fields["J"], not fields["F"]).
    volumetric: ClassVar[bool] = False

    def __init__(self, spec, dim: int):
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        problems = check_params(self.parameters, dict(spec.params))
        if not (math.isfinite(spec.density) and spec.density > 0.0):
            problems.append(f"density: must be > 0, got {spec.density:g}")
        if problems:
            raise SceneError([f"material {spec.name!r} ({self.name}): {p}" for p in problems])
        self.spec = spec
        self.dim = dim
        self.density = float(spec.density)
        self.params = resolve_params(self.parameters, dict(spec.params))
        self.mu = 0.0
        self.lam = 0.0

    def wave_speed(self) -> float:
        """P-wave speed sqrt((lam + 2 mu) / rho) of the small-strain response, for the CFL
        bound."""
        return math.sqrt((self.lam + 2.0 * self.mu) / self.density)

    def configure(self, *, dx: float) -> None:
        """Called by the simulation once the grid is known. Models with a length scale (the
        artificial viscosity of the impact models) keep ``dx``; the default ignores it."""

    def update_stress(self, fields: dict[str, np.ndarray], dt: float) -> None:
        raise NotImplementedError

    def energy(self, fields: dict[str, np.ndarray]) -> float:
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v!r}"
                         for k, v in self.params.items())
        return f"{type(self).__name__}({args}, density={self.density:g}, dim={self.dim})"


class ElasticMaterial(Material):
    """A stateless elastic model given by (E, nu): one stress kernel and one energy kernel per
    dimension, called with the Lamé pair `kernel_moduli()`.

    Kernel signatures: ``stress(F, tau, mu, lam)`` writes tau (n, d, d) from F (n, d, d);
    ``energy(F, vol0, mu, lam) -> float`` returns sum_p vol0_p psi(F_p).
    """

    parameters = {"E": YOUNG, "nu": POISSON}
    stress_kernels: ClassVar[dict[int, Callable]] = {}
    energy_kernels: ClassVar[dict[int, Callable]] = {}

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        self.mu, self.lam = lame(self.params["E"], self.params["nu"])

    def kernel_moduli(self) -> tuple[float, float]:
        """(mu, lam) handed to the kernels; the small-strain pair unless a model
        reparameterises its energy."""
        return self.mu, self.lam

    def update_stress(self, fields: dict[str, np.ndarray], dt: float) -> None:
        """Writes fields["tau"] (n, d, d) from fields["F"] (n, d, d)."""
        self.stress_kernels[self.dim](fields["F"], fields["tau"], *self.kernel_moduli())

    def energy(self, fields: dict[str, np.ndarray]) -> float:
        """sum_p vol0_p psi(F_p)."""
        return float(self.energy_kernels[self.dim](fields["F"], fields["vol0"],
                                                   *self.kernel_moduli()))

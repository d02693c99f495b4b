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
    choices: tuple[str]    non-empty: the value is a string, one of these (low/high unused)

So ``Param(0.0, math.inf)`` is "required, > 0" and ``Param(-1.0, 0.5)`` is "required,
-1 < value < 0.5". A value must be a real number (bool is not) and finite unless a bound is
infinite and inclusive (``relaxation_time`` of oldroyd_b: ``Param(0, inf, high_inclusive=True)``
accepts ``inf``). A choice key such as ``plasticity = "ob_spd"`` has ``choices=(...)`` and a
string default.

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

    low: float
    high: float
    required: bool = True
    default: float | None = None
    low_inclusive: bool = False
    high_inclusive: bool = False
    doc: str = ""
    choices: tuple = ()


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
        if spec.choices:
            if params[key] not in spec.choices:
                problems.append(f"{key}: must be one of {', '.join(map(repr, spec.choices))}, "
                                f"got {params[key]!r}")
            continue
        x = _number(params[key])
        if x is None or math.isnan(x):
            problems.append(f"{key}: must be a number, got {params[key]!r}")
            continue
        if not math.isfinite(x) and not (
                (x == math.inf and spec.high == math.inf and spec.high_inclusive)
                or (x == -math.inf and spec.low == -math.inf and spec.low_inclusive)):
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
    return problems


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
        problems = type(self).parameter_problems(dict(spec.params))
        if not (math.isfinite(spec.density) and spec.density > 0.0):
            problems.append(f"density: must be > 0, got {spec.density:g}")
        if problems:
            raise SceneError([f"material {spec.name!r} ({self.name}): {p}" for p in problems])
        self.spec = spec
        self.dim = dim
        self.density = float(spec.density)
        self.params = {key: (spec.params[key] if p.choices else float(spec.params[key]))
                       if key in spec.params else p.default
                       for key, p in self.parameters.items()}
        self.mu = 0.0
        self.lam = 0.0

    @classmethod
    def parameter_problems(cls, params: dict[str, Any]) -> list[str]:
        """Problems with a scene's parameters: the schema check, plus any rule between keys a
        model adds (e.g. "mu and lambda, or E and nu")."""
        return check_params(cls.parameters, params)

    def wave_speed(self) -> float:
        """P-wave speed sqrt((lam + 2 mu) / rho) of the small-strain response, for the CFL
        bound."""
        return math.sqrt((self.lam + 2.0 * self.mu) / self.density)

    def update_stress(self, fields: dict[str, np.ndarray], dt: float) -> None:
        raise NotImplementedError

    def energy(self, fields: dict[str, np.ndarray]) -> float:
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:g}" for k, v in self.params.items())
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

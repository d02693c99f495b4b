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
from typing import Any, Callable, ClassVar, NamedTuple

import numpy as np

from ..errors import SceneError
from ..scene import _describe
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
    if isinstance(value, bool):
        return None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x


def check_params(parameters: dict[str, Param], params: dict[str, Any]) -> list[str]:
    """Problems with ``params`` against the schema ``parameters``: one string per missing,
    unknown, mistyped or out-of-range key; empty when all is well. Keys of sub-tables are
    reported with their path (``eos.c0: must be > 0, got -1``)."""
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


class Material:
    """A constitutive model: per-particle state, its update over a step, stress, energy and
    wave speed.

    The step calls, per material and on that material's slice of particles:

    - `update_state(fields, dt)` right after G2P: advance the state over the interval ``dt``
      it integrates (F or b_E update from the step's velocity gradient, plastic return map,
      energy update), so frames and checkpoints hold the projected state;
    - `update_stress(fields, dt)` before P2G, chunk by chunk: write the Kirchhoff stress
      ``fields["tau"]`` (n, d, d) = J sigma from the current state, without changing it.

    ``deformation`` says what G2P hands the material (see `hpcmpm.kernels.deformation`):
    ``"F"`` (G2P advances F <- (I + dt L) F), ``"J"`` (its determinant only) or ``"L"`` (G2P
    stores the step's velocity gradient L_p in the field ``"L"`` and the material advances
    its own state in `update_state`). A scene carries L when any material asks for it; then
    the base `update_state` advances F (or J) of the other materials from L itself.

    Subclasses set ``name``, ``parameters``, ``fields`` (their own state), the small-strain
    Lamé parameters ``self.mu``, ``self.lam`` (used by `wave_speed`), and implement
    `update_stress` and `energy` by dispatching once on ``dim`` to a 2D or 3D numba kernel;
    plastic models override `return_map` (after the F update) or `update_state`.

    Semi-implicit integration (000 §3.4, §5.5, appendix A) asks for the incremental potential
    of the step as a function of L with the state at t^n held fixed:
    ``implicit_energy(fields, L, dt) -> float``, ``implicit_gradient(fields, L, dt, G)``
    (G_p = de_p/dL_p) and ``implicit_hessian(fields, L, dt, dL, dG)`` (dG_p = D^2 e_p[dL_p]);
    a material without them (``implicit = False``) runs with the explicit integrator only.
    ``implicit_tangent`` builds the whole d^2 x d^2 tangent from those products; a model may
    override it with one pass that shares its per-particle work between the directions.
    """

    name: ClassVar[str] = ""
    parameters: ClassVar[dict[str, Param]] = {}
    fields: ClassVar[dict[str, FieldSpec]] = {}
    deformation: ClassVar[str] = "F"
    # False: P2G and G2P skip the material's particles (peridynamic bodies that move by
    # their own bond forces, 003 Alg. 2).
    on_grid: ClassVar[bool] = True

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
        self.params = resolve_params(self.parameters, dict(spec.params))
        self.mu = 0.0
        self.lam = 0.0
        # One line per particle whose state became unrecoverable in a kernel (the kernel
        # also writes NaN into its J or F, which the health check finds).
        self.failures: list[str] = []
        # SPB-MPM (003 ch. 6): a `failure` table adds fields and a step extension.
        attach_failure(self)

    @classmethod
    def parameter_problems(cls, params: dict[str, Any]) -> list[str]:
        """Problems with a scene's parameters: the schema check, plus any rule between keys a
        model adds (e.g. "mu and lambda, or E and nu"); `validate_params` and __init__ use
        it."""
        params = dict(params)
        problems = []
        if "failure" in params and "failure" not in cls.parameters:
            problems.append(no_pd_stress_problem(cls.name))   # SPB-MPM, materials/failure.py
            params.pop("failure")
        return problems + check_params(cls.parameters, params)

    @classmethod
    def scene_problems(cls, spec, scene) -> list[str]:
        """Problems of a valid parameter set against the rest of the scene (dimension,
        spacing, domain, other materials), ``"key: what is wrong"`` each: the scene validator
        reports them with the TOML path, like the schema's (`hpcmpm.scene.parse_scene`).
        None by default."""
        return []

    def configure(self, scene) -> None:
        """Called once the scene is known (grid spacing, time-step limits): a model that
        needs them reads them here, and raises SceneError for a combination it cannot run."""

    def side_bytes_per_particle(self) -> int:
        """Bytes a particle of this material holds outside the particle fields (peridynamic
        bonds), for the start-up memory estimate; 0 by default. Call after `configure`."""
        return 0

    @property
    def volumetric(self) -> bool:
        return self.deformation == "J"

    @property
    def updates_state(self) -> bool:
        """Whether `update_state` does any work outside mode "L" (the step skips it
        otherwise, so an elastic scene pays nothing for the phase)."""
        cls = type(self)
        return cls.update_state is not Material.update_state or \
            cls.return_map is not Material.return_map

    def wave_speed(self) -> float:
        """P-wave speed sqrt((lam + 2 mu) / rho) of the small-strain response, for the CFL
        bound."""
        return math.sqrt((self.lam + 2.0 * self.mu) / self.density)

    def max_wave_speed(self, fields: dict[str, np.ndarray]) -> float:
        """Largest wave speed over these particles; state-dependent models (a shock EOS)
        override it. The rest value by default."""
        return self.wave_speed()

    def dt_limit(self, dx: float) -> float:
        """Largest stable explicit time step of the model besides the wave-speed CFL bound
        (e.g. viscous diffusion, rho dx^2 / (2 d mu_N)); unbounded by default."""
        return math.inf

    def update_state(self, fields: dict[str, np.ndarray], dt: float) -> None:
        """After G2P: in mode "L" advance F (or J) by the step's L, then `return_map`."""
        if "L" in fields:
            from ..kernels.deformation import advance_by_velocity_gradient

            target = "J" if self.deformation == "J" else "F"
            advance_by_velocity_gradient(fields[target], fields["L"], dt)
        self.return_map(fields, dt)

    def return_map(self, fields: dict[str, np.ndarray], dt: float) -> None:
        """Plastic projection of the state G2P advanced over ``dt`` (none by default)."""

    def update_stress(self, fields: dict[str, np.ndarray], dt: float) -> None:
        raise NotImplementedError

    def energy(self, fields: dict[str, np.ndarray]) -> float:
        raise NotImplementedError

    implicit: ClassVar[bool] = False

    def implicit_tangent(self, fields, L, dt: float, dL, dG, T) -> None:
        """Writes T (n, d^2, d^2), T_p[ab, ce] = d^2 e_p / dL_ab dL_ce at L_p, one
        `implicit_hessian` product per unit direction E_ce (dL, dG: (n, d, d) scratch)."""
        n, d = L.shape[0], L.shape[-1]
        for c in range(d):
            for e in range(d):
                dL[:] = 0.0
                dL[:, c, e] = 1.0
                self.implicit_hessian(fields, L, dt, dL, dG)
                T[:, :, c * d + e] = dG.reshape(n, d * d)

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


# SPB-MPM (003 ch. 6): the elastic models can turn into peridynamics (materials/failure.py,
# which builds on Param above, hence the import at the end).
from .failure import SPB_FAILURE, attach_failure, no_pd_stress_problem  # noqa: E402

ElasticMaterial.parameters = {**ElasticMaterial.parameters, "failure": SPB_FAILURE}

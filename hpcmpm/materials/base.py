"""The Material base class and ElasticMaterial, the models of F alone. The schema of their
``parameters`` (`Param`, `check_params`) is in `hpcmpm.materials.params`.
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar

import numpy as np

from ..errors import SceneError
from ..kernels.tangent import index_table
from ..state import FieldSpec
from .failure import SPB_FAILURE, attach_failure, no_pd_stress_problem
from .params import POISSON, YOUNG, MATERIAL_TABLE_KEYS, Param, check_params, lame, resolve_params


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
    ``implicit_tangent`` builds the d^2 x d^2 tangent from those products (packed: its upper
    triangle, kernels/tangent.py); a model may override it with one pass that shares its
    per-particle work between the directions.
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
        return problems + check_params(cls.parameters, params, MATERIAL_TABLE_KEYS)

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

    def notes(self) -> list[str]:
        """Lines worth telling the user about this material in its scene (the run log and
        `hpcmpm validate` print them); none by default. Call after `configure`."""
        return []

    def side_bytes_per_particle(self) -> int:
        """Bytes a particle of this material holds outside the particle fields (peridynamic
        bonds), for the start-up memory estimate; 0 by default. Call after `configure`."""
        return 0

    def averages_volume(self, deformation: str) -> bool:
        """Whether ``simulation.volume_averaging`` averages this model's particles: their
        stored J is the volume state the stress reads (hpcmpm/kernels/volume.py). False by
        default; ``deformation`` is the scene's mode (`deformation_mode`)."""
        return False

    @property
    def volumetric(self) -> bool:
        return self.deformation == "J"

    def updates_state(self, deformation: str) -> bool:
        """Whether `update_state` does any work in the scene's ``deformation`` mode outside
        mode "L" (the step skips it otherwise, so an elastic scene pays nothing for the
        phase)."""
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
        """Writes T, T_p[ab, ce] = d^2 e_p / dL_ab dL_ce at L_p packed (n, d^2 (d^2 + 1) / 2)
        as kernels/tangent.py lays it out: one `implicit_hessian` product per unit direction
        E_ce gives column ce, whose entries on and above the diagonal are kept (dL, dG:
        (n, d, d) scratch)."""
        n, d = L.shape[0], L.shape[-1]
        k = d * d
        table = index_table(k)
        for c in range(d):
            for e in range(d):
                dL[:] = 0.0
                dL[:, c, e] = 1.0
                self.implicit_hessian(fields, L, dt, dL, dG)
                column = c * d + e
                T[:, table[: column + 1, column]] = dG.reshape(n, k)[:, : column + 1]

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

    # SPB-MPM (003 ch. 6): an elastic model can turn into peridynamics (materials/failure.py).
    parameters = {"E": YOUNG, "nu": POISSON, "failure": SPB_FAILURE}
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

    def pd_stress(self, fields: dict[str, np.ndarray], F: np.ndarray, tau: np.ndarray) -> None:
        """tau (k, d, d) at the peridynamic deformation gradients F (SPB-MPM,
        `failure.pd_stress`): the model's own stress of F alone."""
        self.stress_kernels[self.dim](F, tau, *self.kernel_moduli())


"""Homogeneous material-point driver: a few material points under a prescribed velocity
gradient L(t), no grid.

Each step does what the engine does to a particle in deformation mode "L": store the step's L
in fields["L"], `update_state(fields, dt)` (a b_E model advances its own state; the base class
advances F, or J, from L and applies the return map), then `update_stress(fields, dt)`; the
stress history is recorded. For verification against closed forms (uniform flows: simple
shear, extension, relaxation) and for convergence and stability studies of the plastic
updates (tests/verification/test_viscoelastic_driver.py, scripts/).

    result = drive(material, lambda t: L, dt=1e-3, steps=1000)
    result.tau[-1]        # Kirchhoff stress at the end, (count, d, d)
    result.sigma()        # Cauchy stress history tau / J, (steps + 1, count, d, d)
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Callable

import numpy as np

from ..errors import InstabilityError
from ..state import SCALAR, TENSOR, FieldSpec


@dataclass
class DriverResult:
    """Histories at t_0 = 0, t_1 = dt, ..., t_steps: ``time`` (steps + 1,), ``tau``
    (steps + 1, count, d, d), ``J`` (steps + 1, count); ``fields`` holds the final state."""

    time: np.ndarray
    tau: np.ndarray
    J: np.ndarray
    fields: dict
    history: dict  # name -> (steps + 1, count, ...) for each field named in ``record``

    def sigma(self) -> np.ndarray:
        """Cauchy stress tau / J."""
        return self.tau / self.J[:, :, None, None]


def initial_fields(material, count: int = 1, state: dict | None = None) -> dict:
    """Particle fields of ``count`` points of ``material`` at rest (unit volume and mass),
    from the material's declared fields and their fills; ``state`` overrides any of them
    (arrays broadcast to (count, ...))."""
    d = material.dim
    deformation = {"F": {"F": FieldSpec(TENSOR, "f8", "identity")},
                   "J": {"J": FieldSpec(SCALAR, "f8", 1.0)}}.get(material.deformation, {})
    specs = {**deformation, **material.fields}
    fields = {"x": np.zeros((count, d)), "v": np.zeros((count, d)), "mass": np.ones(count),
              "vol0": np.ones(count), "id": np.arange(count, dtype=np.int64),
              "L": np.zeros((count, d, d)), "tau": np.zeros((count, d, d))}
    for name, spec in specs.items():
        shape = (count,) + spec.trailing_shape(d)
        if spec.fill == "identity":
            fields[name] = np.tile(np.eye(d), (count, 1, 1))
        else:
            fields[name] = np.full(shape, spec.fill, dtype=spec.dtype)
    for name, value in (state or {}).items():
        fields[name] = np.array(np.broadcast_to(value, fields[name].shape), dtype=np.float64)
    return fields


def step(material, fields: dict, L: np.ndarray, dt: float) -> None:
    """One homogeneous step with velocity gradient L ((d, d) or (count, d, d))."""
    fields["L"][:] = L
    material.update_state(fields, dt)
    material.update_stress(fields, dt)


def volume_ratio(fields: dict) -> np.ndarray:
    """J per point: the stored J, or det F."""
    return fields["J"] if "J" in fields else np.linalg.det(fields["F"])


def drive(material, velocity_gradient: Callable[[float], np.ndarray], dt: float, steps: int,
          count: int = 1, state: dict | None = None, record: tuple = ()) -> DriverResult:
    """Integrate ``count`` points of ``material`` over ``steps`` steps of ``dt``; step n (from
    t_n to t_n+1) uses L = velocity_gradient(t_n+1), the end-of-step (backward Euler) value the
    semi-implicit integrator also uses. Raises FloatingPointError when the material reports
    an inadmissible state (its ``failures``). ``record`` names state fields (e.g. "b") whose
    histories to keep."""
    fields = initial_fields(material, count, state)
    d = material.dim
    tau = np.empty((steps + 1, count, d, d))
    J = np.empty((steps + 1, count))
    history = {name: np.empty((steps + 1,) + fields[name].shape) for name in record}
    material.update_stress(fields, dt)
    tau[0], J[0] = fields["tau"], volume_ratio(fields)
    for name in record:
        history[name][0] = fields[name]
    failures = getattr(material, "failures", None)
    for n in range(steps):
        step(material, fields, velocity_gradient((n + 1) * dt), dt)
        if failures:
            raise FloatingPointError(f"step {n + 1}, t = {(n + 1) * dt:g}: {failures[-1]}")
        tau[n + 1], J[n + 1] = fields["tau"], volume_ratio(fields)
        for name in record:
            history[name][n + 1] = fields[name]
    return DriverResult(np.arange(steps + 1) * dt, tau, J, fields, history)


class MaterialPoint:
    """`initial_fields` and `step` kept together, for tests that drive point by point and
    change the state between steps (the impact models: tests/unit/test_impact_materials.py).

    ``dx`` reaches the material through `configure` as the grid spacing of a scene (the
    artificial viscosity's length). `step` raises InstabilityError with the material's
    failure messages, as the engine's health check does."""

    def __init__(self, material, count: int = 1, dx: float = 1.0, state: dict | None = None):
        material.configure(SimpleNamespace(dx=dx))
        self.material = material
        self.fields = initial_fields(material, count, state)
        self.time = 0.0
        self.steps = 0

    def step(self, L: np.ndarray, dt: float) -> None:
        """One step under the velocity gradient L ((d, d) for all points or (count, d, d))."""
        step(self.material, self.fields, L, dt)
        self.time += dt
        self.steps += 1
        if self.material.failures:
            messages, self.material.failures = self.material.failures, []
            raise InstabilityError(f"step {self.steps}, t = {self.time:g}: "
                                   + "; ".join(messages))

    def cauchy(self) -> np.ndarray:
        """sigma = tau / J (count, d, d) of the last step."""
        return self.fields["tau"] / volume_ratio(self.fields)[:, None, None]

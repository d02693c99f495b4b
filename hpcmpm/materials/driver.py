"""Material-point driver: a batch of particles of one material under a prescribed velocity
gradient, without a grid (for verification of the "L"-mode models and for studies).

Each `step(L, dt)` does what the engine does to a particle between G2P and P2G in deformation
mode "L": store L, `update_state` (the state over dt), `update_stress` (tau from the state).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..errors import InstabilityError
from ..state import SCALAR, TENSOR, FieldSpec, ParticleSet


class MaterialPoint:
    """``n`` material points of ``material`` (an "L"-mode model), all fields at their fill
    values. ``fields`` maps names to (n, ...) views; ``dx`` reaches the material through
    `configure` as the grid spacing of a scene."""

    def __init__(self, material, n: int = 1, dx: float = 1.0):
        self.material = material
        material.configure(SimpleNamespace(dx=dx))
        d = material.dim
        specs = {**material.fields, "L": FieldSpec(TENSOR), "tau": FieldSpec(TENSOR),
                 "J": FieldSpec(SCALAR, "f8", 1.0)}
        self.particles = ParticleSet(d, specs, capacity=n)
        self.particles.append({"id": np.arange(n), "vol0": np.ones(n),
                               "mass": np.full(n, material.density)})
        self.fields = {name: self.particles[name] for name in self.particles.field_names()}
        self.time = 0.0
        self.steps = 0

    def step(self, L: np.ndarray, dt: float) -> None:
        """One step under the velocity gradient L ((d, d) for all points or (n, d, d)).
        Raises InstabilityError with the material's failure messages."""
        self.fields["L"][:] = L
        self.material.update_state(self.fields, dt)
        self.time += dt
        self.steps += 1
        if self.material.failures:
            messages, self.material.failures = self.material.failures, []
            raise InstabilityError(f"step {self.steps}, t = {self.time:g}: "
                                   + "; ".join(messages))
        self.material.update_stress(self.fields, dt)

    def cauchy(self) -> np.ndarray:
        """sigma = tau / J (n, d, d) of the last step."""
        return self.fields["tau"] / self.fields["J"][:, None, None]

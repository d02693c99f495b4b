"""Time integrators, looked up by the scene's ``simulation.integrator``.

An integrator is a short list of the `Simulation`'s phases (`explicit.ExplicitIntegrator`) plus
its time-step rule. `INTEGRATORS` maps each name to its class; `make_integrator(name, sim)`
builds one.

Interface::

    class Integrator:
        name: ClassVar[str]
        needs_velocity_gradient: ClassVar[bool]   # particles carry L (mode "L")
        def __init__(self, sim)
        def grid_step(self, sim, dt) -> None       # the step's grid phases (P2G .. state
                                                   # update); `Simulation.step` runs the
                                                   # sort before and the extensions after
        def stable_dt(self, sim, speed) -> float   # speed: global max |v_p|
        @staticmethod
        def scratch_bytes_per_particle(dim) -> int # per-particle arrays it allocates (at
                                                   # the particles' capacity), for the
                                                   # start-up memory estimate
"""

from __future__ import annotations

from ..errors import SceneError
from .explicit import ExplicitIntegrator
from .semi_implicit import SemiImplicitIntegrator

INTEGRATORS = {cls.name: cls for cls in (ExplicitIntegrator, SemiImplicitIntegrator)}


def make_integrator(name: str, sim):
    cls = INTEGRATORS.get(name)
    if cls is None:
        raise SceneError(f"simulation.integrator: unknown integrator {name!r} "
                         f"(valid: {', '.join(INTEGRATORS)})")
    return cls(sim)


__all__ = ["INTEGRATORS", "ExplicitIntegrator", "SemiImplicitIntegrator", "make_integrator"]

"""Oldroyd-B viscoelasticity with volume-preserving plastic flow (000 ch. 5; §4.6.1, §4.7.1,
§6.1.4), on the elastic left Cauchy-Green strain.

The conformation b_OB relaxes towards I with the relaxation time Wi (000 §5.4.3):
upper-convected derivative of b_OB = (I - b_OB) / Wi. The stress uses
b_E = (J^2 / det b_OB)^(1/d) b_OB (eq. 5.5, 5.13), so the plastic flow is isochoric, with the
compressible Neo-Hookean energy of eq. 5.8 and Newtonian viscosity (eq. 5.10-5.11, corrected:
see `hpcmpm.materials.left_cauchy_green`). mu = 0 is a compressible Newtonian fluid,
Wi = inf a Neo-Hookean solid on b (the 000 eq. 5.8 form, lam/2 (J - 1)^2). With mu = 0 the
conformation is not advanced (it would grow without bound under steady shear and enters
nothing): b stays I and only J evolves, whatever ``plasticity`` says.

``plasticity`` picks the time discretisation of the relaxation (S, R, B in the kernels module):

    "ob_spd" (default)  §4.6.1, implicit relaxation: b stays SPD for every dt
    "ob_explicit"       eq. 5.14 as printed; b loses definiteness for dt > Wi (§5.7), so a
                        scene whose dt can exceed Wi is rejected (`time_step_problem`)
    "fe"                §4.7.1, F_E with b = F_E F_E^T: SPD by construction; explicit
                        relaxation, stable for dt/Wi < 2 in relaxation (linearised: e' = (1 - r)
                        e) and 1.25-1.45 in start-up shear (measured); dt > Wi rejected
    "fe_bdf2"           §6.1.4, second-order BDF2 on F_E (constant dt assumed; the first step,
                        and a particle without history, by "fe"); stable for dt/Wi < 4 in
                        relaxation (linear theory, measured 3.97) and 1.6-2.0 in start-up shear
                        (W = 5 ... 0.5, measured); dt > Wi rejected; explicit integrator only
                        (`integrator_problem`)

The particle field ``b`` holds the unscaled conformation b_OB (000 §5.5); `elastic_strain`
gives b_E.
"""

from __future__ import annotations

import math

from .left_cauchy_green import (ELASTIC_KEYS, FE, FE_BDF2, FLUID, OB_EXPLICIT, OB_SPD,
                                PLASTICITY_MODES, LeftCauchyGreenMaterial)
from .params import Param, choice
from ..state import TENSOR, FieldSpec


class OldroydB(LeftCauchyGreenMaterial):
    """Volume-preserving Oldroyd-B (000 ch. 5) with a choice of relaxation update."""

    name = "oldroyd_b"
    parameters = {
        **ELASTIC_KEYS,
        "relaxation_time": Param(0.0, math.inf, high_inclusive=True,
                                 doc="relaxation (Weissenberg) time Wi (time units); inf: no "
                                     "relaxation, a hyperelastic solid"),
        "plasticity": choice(tuple(PLASTICITY_MODES), "ob_spd",
                             doc="relaxation update: ob_spd (default, SPD for every dt), "
                                 "ob_explicit (eq. 5.14, needs dt <= relaxation_time), fe, "
                                 "fe_bdf2"),
    }

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        self.plasticity = self.params["plasticity"]
        self.mode = PLASTICITY_MODES[self.plasticity]
        self.relaxation_time = self.params["relaxation_time"]
        self.inv_wi = 1.0 / self.relaxation_time  # 0.0 for inf
        if self.mu == 0.0:
            # A Newtonian fluid: no conformation to relax (left_cauchy_green.FLUID), so no
            # F_E fields and no relaxation bound whatever `plasticity` says.
            self.mode = FLUID
        if self.mode in (FE, FE_BDF2):
            self.fields["Fe"] = FieldSpec(TENSOR, "f8", "identity")
        if self.mode == FE_BDF2:
            # Zero (det 0) marks "no F_E^{n-1} yet": that particle's next step is an fe step.
            self.fields["Fe_prev"] = FieldSpec(TENSOR, "f8", 0.0)

    def time_step_problem(self, max_dt: float) -> str | None:
        """The problem, as "key: what is wrong", when the scene's largest time step ``max_dt``
        breaks this update's bound, else None. ob_explicit: dt <= relaxation_time, beyond which
        b loses definiteness (000 §5.7). fe and fe_bdf2 relax explicitly: measured stability
        limits dt/Wi = 1.25-2 (fe) and 1.6-4 (fe_bdf2; scripts/study_viscoelastic.py), so the
        same bound. ob_spd has none."""
        if self.mode in (OB_SPD, FLUID) or max_dt <= self.relaxation_time:
            return None
        why = ("b loses definiteness beyond (000 §5.7)" if self.mode == OB_EXPLICIT else
               "its explicit relaxation is unstable beyond")
        return (f"plasticity: {self.plasticity!r} needs dt <= relaxation_time ({why}), but the "
                f"time step can reach {max_dt:g} > relaxation_time = "
                f"{self.relaxation_time:g}; use plasticity = 'ob_spd' or set "
                f"simulation.max_dt <= {self.relaxation_time:g}")

    def run_problems(self, scene) -> list[str]:
        """The integrator and time-step bounds of the relaxation update."""
        problems = [self.integrator_problem(getattr(scene, "integrator", "explicit")),
                    self.time_step_problem(self.largest_time_step(scene))]
        return [p for p in problems if p]

    def integrator_problem(self, integrator: str) -> str | None:
        """The problem, as "key: what is wrong", when this update cannot run under
        ``integrator`` ("explicit" | "semi_implicit"), else None.

        fe_bdf2 is explicit only: its L enters b_hat with BDF2's factor 2 dt/3, so the
        potential's force -de/dx_hat is tau_vol + (2/3) tau_dev at rest, not the eq. 5.9 force
        (tests/unit/test_implicit_derivatives.py::test_fe_bdf2_force_at_rest); the semi-implicit
        step, which is backward Euler in the momentum, would be inconsistent."""
        if self.mode == FE_BDF2 and integrator == "semi_implicit":
            return ("plasticity: 'fe_bdf2' runs with the explicit integrator only (its "
                    "semi-implicit force is 2/3 of the deviatoric stress); use 'fe' or 'ob_spd'")
        return None

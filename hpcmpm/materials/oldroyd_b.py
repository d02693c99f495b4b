"""Oldroyd-B viscoelasticity with volume-preserving plastic flow (000 ch. 5; §4.6.1, §4.7.1,
§6.1.4), on the elastic left Cauchy-Green strain.

The conformation b_OB relaxes towards I with the relaxation time Wi (000 §5.4.3):
upper-convected derivative of b_OB = (I - b_OB) / Wi. The stress uses
b_E = (J^2 / det b_OB)^(1/d) b_OB (eq. 5.5, 5.13), so the plastic flow is isochoric, with the
compressible Neo-Hookean energy of eq. 5.8 and Newtonian viscosity (eq. 5.10-5.11, corrected:
see `hpcmpm.materials.left_cauchy_green`). mu = 0 is a compressible Newtonian fluid,
Wi = inf a Neo-Hookean solid on b (the 000 eq. 5.8 form, lam/2 (J - 1)^2).

``plasticity`` picks the time discretisation of the relaxation (S, R, B in the kernels module):

    "ob_spd" (default)  §4.6.1, implicit relaxation: b stays SPD for every dt
    "ob_explicit"       eq. 5.14 as printed; b loses definiteness for dt > Wi (§5.7), so a
                        scene whose dt can exceed Wi is rejected (`time_step_problem`)
    "fe"                §4.7.1, F_E with b = F_E F_E^T: SPD by construction; explicit
                        relaxation, stable for dt/Wi <= 2 (linearised)
    "fe_bdf2"           §6.1.4, second-order BDF2 on F_E (constant dt assumed; the first step,
                        and a particle without history, by "fe")

The particle field ``b`` holds the unscaled conformation b_OB (000 §5.5); `elastic_strain`
gives b_E.
"""

from __future__ import annotations

import math

from .base import Param
from .left_cauchy_green import (ELASTIC_KEYS, FE, FE_BDF2, OB_EXPLICIT, PLASTICITY_MODES,
                                LeftCauchyGreenMaterial)
from ..state import TENSOR, FieldSpec


class OldroydB(LeftCauchyGreenMaterial):
    """Volume-preserving Oldroyd-B (000 ch. 5) with a choice of relaxation update."""

    name = "oldroyd_b"
    parameters = {
        **ELASTIC_KEYS,
        "relaxation_time": Param(0.0, math.inf, high_inclusive=True,
                                 doc="relaxation (Weissenberg) time Wi (time units); inf: no "
                                     "relaxation, a hyperelastic solid"),
        "plasticity": Param(-math.inf, math.inf, required=False, default="ob_spd",
                            choices=tuple(PLASTICITY_MODES),
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
        if self.mode in (FE, FE_BDF2):
            self.fields["Fe"] = FieldSpec(TENSOR, "f8", "identity")
        if self.mode == FE_BDF2:
            # Zero (det 0) marks "no F_E^{n-1} yet": that particle's next step is an fe step.
            self.fields["Fe_prev"] = FieldSpec(TENSOR, "f8", 0.0)

    def time_step_problem(self, max_dt: float) -> str | None:
        """The problem, as "key: what is wrong", when the scene's largest time step ``max_dt``
        breaks this model's bound (ob_explicit: dt <= relaxation_time); None otherwise."""
        if self.mode == OB_EXPLICIT and max_dt > self.relaxation_time:
            return (f"plasticity: 'ob_explicit' needs dt <= relaxation_time (000 §5.7: b loses "
                    f"definiteness beyond), but the time step can reach {max_dt:g} > "
                    f"relaxation_time = {self.relaxation_time:g}; use plasticity = 'ob_spd' or "
                    f"set simulation.max_dt <= {self.relaxation_time:g}")
        return None

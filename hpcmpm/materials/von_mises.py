"""Rate-independent von Mises plasticity on the elastic left Cauchy-Green strain (000 §4.2.6,
§4.3; Simo 1988).

Elastic predictor b_hat = (I + dt L) b^n (I + dt L)^T (the ob_spd update with Wi = inf), then a
radial return of the deviatoric part of the isochoric strain b_bar = b_hat / det(b_hat)^(1/d):
if |dev b_bar| > sigma_Y, dev b_bar <- sigma_Y dev b_bar / |dev b_bar| with tr b_bar kept, and
finally the rescale det b = J^2 (000 §4.3: the plastic flow is isochoric). sigma_Y
(``yield_strain``) is the same strain as Herschel-Bulkley's, so the shear plateau is
tau_y = mu sigma_Y / sqrt(2) (small strain), the rate-independent limit of that model. The
semi-implicit hooks use the elastic predictor; the return acts after the solve, in
update_state.
"""

from __future__ import annotations

import math

from .herschel_bulkley import YIELD_STRAIN
from .left_cauchy_green import ELASTIC_KEYS, FLOW_UPDATE, VM, LeftCauchyGreenMaterial


class VonMises(LeftCauchyGreenMaterial):
    """von Mises plasticity on b_E with radial return (Simo 1988)."""

    name = "von_mises"
    mode = VM
    explicit_mode = VM
    rescale_state = True
    parameters = {**ELASTIC_KEYS, "yield_strain": YIELD_STRAIN, "flow_update": FLOW_UPDATE}

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        self.sigma_y = self.params["yield_strain"]
        self._init_flow_update()

    def run_problems(self, scene) -> list[str]:
        """The flow update against the integrator and dimension (`flow_update_problems`)."""
        return self.flow_update_problems(scene)

    def shear_yield_stress(self) -> float:
        """tau_y = mu sigma_Y / sqrt(2), the simple-shear plateau (small strain)."""
        return self.mu * self.sigma_y / math.sqrt(2.0)

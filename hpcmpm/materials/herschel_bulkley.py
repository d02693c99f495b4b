"""Herschel-Bulkley viscoplasticity on the elastic left Cauchy-Green strain (000 §4.2.5,
§4.6.2; Yue et al. 2015), with the volume-preserving rescale of 000 eq. 5.5.

Flow rule, evaluated on b^n (the stored, rescaled strain, det b^n = J^2):

    gdot  = max(0, (|dev b^n| - sigma_Y) / eta)^(1/h)
    alpha = (2 dt / d) tr b^n gdot / |dev b^n|   (0 when dev b^n = 0),  beta = tr b^n / d
    b_hat = [(I + dt L) b^n (I + dt L)^T + alpha beta I] / (1 + alpha)       (§4.6.2, SPD)
    b^{n+1} = (J^2 / det b_hat)^(1/d) b_hat

sigma_Y (``yield_strain``) is a strain, h (``flow_index``) is 1 for Bingham, < 1 shear
thinning, > 1 shear thickening, and eta (``flow_consistency``) has units time^h. The literal
§4.6.2 never rescales: det b then grows without bound in steady shear and the stress keeps
falling, so there is no steady flow curve. With the rescale the steady simple-shear stress is

    tau = tau_y + K gdot^h,  tau_y = mu sigma_Y / sqrt(2),  K = mu eta 2^(-(h+1)/2)

(small-strain limit; tests/verification/test_viscoelastic_driver.py). The print's 3D
constant 2/3 is 2/d here. Stress, energy and viscosity as in oldroyd_b.py.
"""

from __future__ import annotations

import math

from .left_cauchy_green import ELASTIC_KEYS, FLOW_UPDATE, HB, LeftCauchyGreenMaterial
from .params import Param

YIELD_STRAIN = Param(0.0, math.inf, low_inclusive=True,
                     doc="yield strain sigma_Y: flow when |dev b_E| > sigma_Y (dimensionless)")


class HerschelBulkley(LeftCauchyGreenMaterial):
    """Herschel-Bulkley-like fluid of 000 §4.6.2 with the volume-preserving rescale."""

    name = "herschel_bulkley"
    mode = HB
    explicit_mode = HB
    rescale_state = True
    parameters = {
        **ELASTIC_KEYS,
        "yield_strain": YIELD_STRAIN,
        "flow_index": Param(0.0, math.inf, required=False, default=1.0,
                            doc="flow index h: 1 Bingham, < 1 shear thinning, > 1 thickening"),
        "flow_consistency": Param(0.0, math.inf,
                                  doc="flow consistency eta (units time^h)"),
        "flow_update": FLOW_UPDATE,
    }

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        self.sigma_y = self.params["yield_strain"]
        self.inv_h = 1.0 / self.params["flow_index"]
        self.eta = self.params["flow_consistency"]
        self._init_flow_update()

    def run_problems(self, scene) -> list[str]:
        """The flow update against the integrator and dimension (`flow_update_problems`)."""
        return self.flow_update_problems(scene)

    def flow_curve(self, shear_rate: float) -> float:
        """Steady simple-shear stress tau_y + K gdot^h of the elastic part (small strain)."""
        h = self.params["flow_index"]
        return (self.mu * self.sigma_y / math.sqrt(2.0)
                + self.mu * self.eta * 2.0 ** (-(h + 1.0) / 2.0) * shear_rate ** h)

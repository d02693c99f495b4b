"""What the impact models (`shock`, `j2`; 003 ch. 7) share: deformation mode "L", the
volumetric response of `eos` (an EOS or p = -K ln J, with artificial viscosity), the grid
spacing as the viscosity's length, the state-dependent wave speed and the failure messages.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .base import Material
from .eos import MAX_REPORTED, effective_speed, failure_messages, pressure, sound_speed_sq


@njit(cache=True, inline="always")
def kirchhoff2(J, dev, pq):
    """tau = J (dev - pq I) for a 2x2 deviator tuple and the isotropic p + q."""
    return (J * (dev[0] - pq), J * dev[1], J * dev[2], J * (dev[3] - pq))


@njit(cache=True, inline="always")
def kirchhoff3(J, dev, pq):
    """tau = J (dev - pq I) for a 3x3 deviator tuple and the isotropic p + q."""
    return (J * (dev[0] - pq), J * dev[1], J * dev[2],
            J * dev[3], J * (dev[4] - pq), J * dev[5],
            J * dev[6], J * dev[7], J * (dev[8] - pq))


@njit(cache=True)
def max_effective_speed(L, J, E, shear, kind, rho0, c0, s, gamma0, K, length, q1, q2):
    """max_p of the state-dependent speed Q + sqrt(Q^2 + c^2) (`eos`); L (n, d, d)."""
    d = L.shape[1]
    top = 0.0
    for p in range(J.shape[0]):
        pr, dp = pressure(J[p], E[p], kind, rho0, c0, s, gamma0, K)
        c = math.sqrt(sound_speed_sq(J[p], pr, dp, kind, rho0, gamma0, shear))
        tr_d = 0.0
        for a in range(d):
            tr_d += L[p, a, a]
        v = effective_speed(c, tr_d, length, q1, q2)
        if v > top:
            top = v
    return top


class ImpactMaterial(Material):
    """What the shock and J2 models share: deformation mode "L", an EOS or Hencky pressure
    with artificial viscosity, the grid spacing for its length scale, failure messages."""

    deformation = "L"

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        self.length: float | None = None
        self._bad_index = np.empty(MAX_REPORTED, dtype=np.int64)
        self._bad_J = np.empty(MAX_REPORTED)

    def configure(self, scene) -> None:
        """The artificial viscosity's length l = scene.dx, the grid spacing (`eos`)."""
        self.length = float(scene.dx)

    def viscosity_args(self) -> tuple[float, float, float]:
        """(l, Q1, Q2) for the kernels; the simulation must have called `configure`."""
        vol = self.volumetric_response
        if vol.viscous and self.length is None:
            raise RuntimeError(f"material {self.spec.name!r}: artificial viscosity needs the "
                               f"grid spacing: call configure(scene) before stepping")
        return (self.length or 0.0), vol.q1, vol.q2

    def report(self, fields, nbad: int) -> None:
        """Turn a kernel's failure count into messages in self.failures."""
        if nbad:
            k = min(nbad, MAX_REPORTED)
            ids = fields["id"][self._bad_index[:k]] if "id" in fields else self._bad_index[:k]
            self.failures += failure_messages(self.spec.name, ids, self._bad_J[:k], nbad,
                                              self.volumetric_response)

    def wave_speed(self) -> float:
        """Rest P-wave speed sqrt(c^2) of `eos.sound_speed_sq` at J = 1, E = 0."""
        vol = self.volumetric_response
        dp = vol.K  # dp/dzeta at rest, both kinds
        return math.sqrt((dp + self.shear_term) / self.density)

    def max_wave_speed(self, fields) -> float:
        """Largest state-dependent speed on this slice, artificial viscosity included."""
        if len(fields["J"]) == 0:
            return 0.0
        return float(max_effective_speed(fields["L"], fields["J"], fields["E"],
                                         self.shear_term, *self.volumetric_response.args,
                                         *self.viscosity_args()))

    def pd_stress(self, fields, F, tau) -> None:
        """SPB-MPM's sigma^PD (003 Alg. 3 line 15, corrected): the particle's own Cauchy
        stress from its own state (shock: the deviator of F_E and the MPM pressure, "reuse
        the MPM pressure" of 003 §7.2.2; j2: s - (p + q) I), so the bonds carry the stress
        the material has; these models keep no total F to evaluate at F^PD. The Kirchhoff
        stress handed to the correspondence force (P = tau F^-T) is det(F^PD) sigma, so
        P = sigma cof(F^PD) stays bounded for a family that has nearly collapsed (J sigma
        F^-T with the material's J blew up there: a watermelon run crushed a rind particle
        to rho/rho0 = 12); a family with det F^PD <= 0 carries none. ``fields`` holds the PD
        rows' state and their L (with exclusive coupling the PD family's rate, for q; the
        state itself advances with that rate too: `SPBExtension._pd_velocity_gradient`)."""
        self.update_stress({**fields, "tau": tau}, 0.0)
        J = fields["J"]
        detF = np.linalg.det(F) if len(F) else np.empty(0)
        scale = np.where(detF > 0.0, detF / J, 0.0)
        tau *= scale[:, None, None]

    def energy(self, fields) -> float:
        """sum_p vol0_p E_p: the internal energy (elastic and dissipated) of the slice."""
        return float(np.dot(fields["vol0"], fields["E"]))

"""The shock-wave effects model (003 §7.2.2): stable Neo-Hookean shear, an EOS for the volume.

    sigma = dev(J_E^-1 P_SNH(F_E) F_E^T) - (p + q) I,   tau = J sigma            (003 §7.2.2)

P_SNH is the stable Neo-Hookean stress (003 eq. 7.2, `stable_neo_hookean`); only its deviator
is kept, J_E^-1 mu I_C/(I_C + 1) dev(F_E F_E^T) (the volumetric lam (J - alpha) term is a
multiple of I and drops out). p is the Mie-Grüneisen pressure of the *total* volume ratio
J = det F and the internal energy E (`eos`, corrected 003 eq. 7.4), q the artificial
viscosity. Table 7.1's "DP" plasticity is the snow clamp (Stomakhin 2013; 003 §3.3.3) of the
singular values of F_E to [1 - theta_c, 1 + theta_s]; without theta_c/theta_s F_E is the whole
F. The clamp bounds only the shear: the volume answers to the EOS whatever F_E does.

In 2D the model is the 2D continuum of the house stable Neo-Hookean (d = 2 in I_C - d, its
2D Lamé reparameterisation, the 2D deviator): its P-wave modulus is rho0 c0^2 + mu, against
rho0 c0^2 + 4/3 mu in 3D.

Deformation mode "L": `update_state` advances the particle's own state from the step's
velocity gradient L (fields["L"]): F_E <- (I + dt L) F_E then the clamp,
J <- det(I + dt L) J (the volume change of the step's map x + dt v(x), as the engine advances
F: a density consistent with where the particles go), and E, p by the energy balance of
`eos`. `update_stress` writes tau from that state and the stored L (for q), changing nothing.

Fields: F_E (elastic deformation gradient), J (total volume ratio), E (internal energy per
reference volume), pressure (EOS pressure p, without q, for output).
"""

from __future__ import annotations

import math

from numba import njit

from ..state import SCALAR, TENSOR, FieldSpec
from .decompositions import svd2, svd3
from .eos import (EOS_SCHEMA, VISCOSITY_PARAMS, Volumetric, record_failure, total_pressure,
                  volume_step)
from .failure import SPB_FAILURE
from .impact import ImpactMaterial, kirchhoff2, kirchhoff3
from .params import POISSON, Param, lame, table
from .tensors import (det2, det3, frob2, frob3, load2, load3, mul2, mul2_bt, mul3, mul3_bt,
                      store2, store3)


# -- deviatoric Cauchy stress of the stable Neo-Hookean model ------------------------------
@njit(cache=True, inline="always")
def snh_dev_cauchy_2d(f, mu):
    """dev(J^-1 P_SNH(F) F^T) for a 2x2 tuple F; mu is the energy's (reparameterised)
    modulus: J^-1 mu I_C/(I_C + 1) dev(F F^T) (003 eq. 7.2)."""
    ic = frob2(f)
    m = mu * ic / ((ic + 1.0) * det2(f))
    b = mul2_bt(f, f)
    h = 0.5 * (b[0] + b[3])
    return (m * (b[0] - h), m * b[1], m * b[2], m * (b[3] - h))


@njit(cache=True, inline="always")
def snh_dev_cauchy_3d(f, mu):
    """dev(J^-1 P_SNH(F) F^T) for a 3x3 tuple F (see the 2D version)."""
    ic = frob3(f)
    m = mu * ic / ((ic + 1.0) * det3(f))
    b = mul3_bt(f, f)
    # Each diagonal entry as a difference of the others, so an isotropic b gives an exact 0.
    third = m / 3.0
    return (third * (2.0 * b[0] - b[4] - b[8]), m * b[1], m * b[2],
            m * b[3], third * (2.0 * b[4] - b[0] - b[8]), m * b[5],
            m * b[6], m * b[7], third * (2.0 * b[8] - b[0] - b[4]))


@njit(cache=True, inline="always")
def _clamp(s, lo, hi):
    return min(max(s, lo), hi)


# -- state update (after G2P) ----------------------------------------------------------------
@njit(cache=True)
def _update_state_2d(L, F_E, J, E, P, dt, mu, shear, clamp, lo, hi, kind, rho0, c0, s,
                     gamma0, K, length, q1, q2, bad_index, bad_J):
    """F_E, J, E, P (n, ...) advanced over dt from L (n, 2, 2); returns the number of
    particles whose EOS failed (their J becomes NaN; the first ones go to bad_index/bad_J)."""
    nbad = 0
    for p in range(L.shape[0]):
        l = load2(L, p)
        fe = mul2((1.0 + dt * l[0], dt * l[1], dt * l[2], 1.0 + dt * l[3]), load2(F_E, p))
        if clamp:
            U, s0, s1, V = svd2(fe)
            c0_, c1_ = _clamp(s0, lo, hi), _clamp(s1, lo, hi)
            if c0_ != s0 or c1_ != s1:
                fe = mul2_bt((U[0] * c0_, U[1] * c1_, U[2] * c0_, U[3] * c1_), V)
        store2(F_E, p, fe)
        sd = snh_dev_cauchy_2d(fe, mu)
        ratio = (1.0 + dt * l[0]) * (1.0 + dt * l[3]) - dt * dt * l[1] * l[2]
        J1, E1, p1 = volume_step(J[p], E[p], ratio, l[0] + l[3], dt,
                                 sd[0] * l[0] + sd[1] * l[1] + sd[2] * l[2] + sd[3] * l[3],
                                 shear, kind, rho0, c0, s, gamma0, K, length, q1, q2)
        if not math.isfinite(p1):
            nbad = record_failure(p, J1, nbad, bad_index, bad_J)
            J[p] = math.nan
            continue
        J[p] = J1
        E[p] = E1
        P[p] = p1
    return nbad


@njit(cache=True)
def _update_state_3d(L, F_E, J, E, P, dt, mu, shear, clamp, lo, hi, kind, rho0, c0, s,
                     gamma0, K, length, q1, q2, bad_index, bad_J):
    """3D version of `_update_state_2d`."""
    nbad = 0
    for p in range(L.shape[0]):
        l = load3(L, p)
        A = (1.0 + dt * l[0], dt * l[1], dt * l[2],
             dt * l[3], 1.0 + dt * l[4], dt * l[5],
             dt * l[6], dt * l[7], 1.0 + dt * l[8])
        fe = mul3(A, load3(F_E, p))
        if clamp:
            U, s0, s1, s2, V = svd3(fe)
            a0, a1, a2 = _clamp(s0, lo, hi), _clamp(s1, lo, hi), _clamp(s2, lo, hi)
            if a0 != s0 or a1 != s1 or a2 != s2:
                fe = mul3_bt((U[0] * a0, U[1] * a1, U[2] * a2,
                              U[3] * a0, U[4] * a1, U[5] * a2,
                              U[6] * a0, U[7] * a1, U[8] * a2), V)
        store3(F_E, p, fe)
        sd = snh_dev_cauchy_3d(fe, mu)
        work = 0.0
        for k in range(9):
            work += sd[k] * l[k]
        J1, E1, p1 = volume_step(J[p], E[p], det3(A), l[0] + l[4] + l[8], dt, work, shear,
                                 kind, rho0, c0, s, gamma0, K, length, q1, q2)
        if not math.isfinite(p1):
            nbad = record_failure(p, J1, nbad, bad_index, bad_J)
            J[p] = math.nan
            continue
        J[p] = J1
        E[p] = E1
        P[p] = p1
    return nbad


# -- stress (before P2G) ---------------------------------------------------------------------
@njit(cache=True)
def _stress_2d(L, F_E, J, E, tau, mu, shear, kind, rho0, c0, s, gamma0, K, length, q1, q2):
    """tau = J (dev sigma_SNH(F_E) - (p + q) I), (n, 2, 2); q from the stored L."""
    for p in range(J.shape[0]):
        sd = snh_dev_cauchy_2d(load2(F_E, p), mu)
        Jp = J[p]
        pq = total_pressure(Jp, E[p], L[p, 0, 0] + L[p, 1, 1], shear, kind, rho0, c0, s,
                            gamma0, K, length, q1, q2)
        store2(tau, p, kirchhoff2(Jp, sd, pq))


@njit(cache=True)
def _stress_3d(L, F_E, J, E, tau, mu, shear, kind, rho0, c0, s, gamma0, K, length, q1, q2):
    """3D version of `_stress_2d`."""
    for p in range(J.shape[0]):
        sd = snh_dev_cauchy_3d(load3(F_E, p), mu)
        Jp = J[p]
        pq = total_pressure(Jp, E[p], L[p, 0, 0] + L[p, 1, 1] + L[p, 2, 2], shear, kind, rho0,
                            c0, s, gamma0, K, length, q1, q2)
        store3(tau, p, kirchhoff3(Jp, sd, pq))


class ShockModel(ImpactMaterial):
    """003 §7.2.2 shock-wave effects model (module docstring)."""

    name = "shock"
    parameters = {
        "E": Param(0.0, math.inf, low_inclusive=True,
                   doc="Young's modulus of the shear response (0: a fluid)"),
        "nu": POISSON,
        "theta_c": Param(0.0, 1.0, required=False, low_inclusive=True,
                         doc="snow clamp: singular values of F_E >= 1 - theta_c; none if absent"),
        "theta_s": Param(0.0, math.inf, required=False, low_inclusive=True,
                         doc="snow clamp: singular values of F_E <= 1 + theta_s; none if absent"),
        "eos": table(EOS_SCHEMA, required=True, doc="equation of state table"),
        **VISCOSITY_PARAMS,
        "failure": SPB_FAILURE,
    }
    fields = {"F_E": FieldSpec(TENSOR, "f8", "identity"), "J": FieldSpec(SCALAR, "f8", 1.0),
              "E": FieldSpec(SCALAR, "f8", 0.0), "pressure": FieldSpec(SCALAR, "f8", 0.0)}
    uses_svd = True

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        q = self.params
        self.mu, self.lam = lame(q["E"], q["nu"])
        d = float(dim)
        # The stable Neo-Hookean reparameterisation (stable_neo_hookean): the deviator of the
        # energy's mu d/(d+1) (H + H^T) is 2 mu_LE dev(eps), so shear waves travel at
        # sqrt(mu_LE / rho) as in every other model given E, nu.
        self.mu_energy = (d + 1.0) / d * self.mu
        self.shear_term = 2.0 * (d - 1.0) / d * self.mu
        self.volumetric_response = Volumetric(q["eos"], self.density, 0.0, q["q1"], q["q2"])
        self.clamp = q["theta_c"] is not None or q["theta_s"] is not None
        self.lower = -math.inf if q["theta_c"] is None else 1.0 - q["theta_c"]
        self.upper = math.inf if q["theta_s"] is None else 1.0 + q["theta_s"]
        self.uses_svd = self.clamp
        self._state = _update_state_2d if dim == 2 else _update_state_3d
        self._stress = _stress_2d if dim == 2 else _stress_3d

    def update_state(self, fields, dt: float) -> None:
        """Advance F_E (clamped), J, E and pressure over dt from fields["L"]."""
        nbad = self._state(fields["L"], fields["F_E"], fields["J"], fields["E"],
                           fields["pressure"], dt, self.mu_energy, self.shear_term,
                           self.clamp, self.lower, self.upper, *self.volumetric_response.args,
                           *self.viscosity_args(), self._bad_index, self._bad_J)
        self.report(fields, nbad)

    def update_stress(self, fields, dt: float) -> None:
        """Write fields["tau"] (n, d, d) = J sigma from the state and the stored L."""
        self._stress(fields["L"], fields["F_E"], fields["J"], fields["E"], fields["tau"],
                     self.mu_energy, self.shear_term, *self.volumetric_response.args,
                     *self.viscosity_args())

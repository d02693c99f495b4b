"""Weakly compressible fluid: pressure from the volume ratio J only, no shear stiffness.

psi(J) = E (J - 1 - ln J),   tau = P F^T = J psi'(J) I = E (J - 1) I,   p = -E (J - 1)/J.

This is the fluid of Taichi's mpm88 example made energy-consistent. mpm88 tracks J alone and
adds ``-dt * 4 * E * p_vol * (J - 1) / dx**2`` to the MLS affine matrix; in MLS-MPM (Hu et al.
2018) the stress term of that matrix is ``-dt * vol0 * D^-1 * tau`` with D^-1 = 4/dx^2 for
quadratic B-splines, so mpm88's term is exactly tau = E (J - 1) I with vol0 = p_vol. The energy
whose Kirchhoff stress that is follows from tau = J psi'(J) I; it is convex, zero at J = 1 and
grows without bound as J -> 0. (psi = E/2 (J - 1)^2 would give tau = E (J - 1) J I instead,
which differs from mpm88 at finite compression.) E is the bulk modulus at rest, so the sound
speed is sqrt(E / rho).

A fluid has no memory of shape: J is its only state. A scene whose materials are all
volumetric carries J alone (`deformation = "J"`; see `hpcmpm.kernels.deformation`); in a scene
that also holds solids the fluid's particles carry F like the others, and after the stress is
computed F is reset to J^(1/d) I, which keeps J and keeps F well conditioned however much the
flow shears it (as Taichi's mpm99 does for its fluid).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..kernels.deformation import volume_ratio
from .base import Material
from .implicit import j_energy, j_gradient, j_hessian
from .matrix import EYE
from .params import Param
from .tensors import det2, det3, load2, load3


@njit(cache=True)
def _forget_shear_2d(F):
    """F_p <- sqrt(J_p) I; F (n, 2, 2)."""
    for p in range(F.shape[0]):
        r = math.sqrt(det2(load2(F, p)))  # NaN for J <= 0, which the health check reports
        F[p, 0, 0] = r
        F[p, 0, 1] = 0.0
        F[p, 1, 0] = 0.0
        F[p, 1, 1] = r


@njit(cache=True)
def _forget_shear_3d(F):
    """F_p <- J_p^(1/3) I; F (n, 3, 3)."""
    for p in range(F.shape[0]):
        r = det3(load3(F, p)) ** (1.0 / 3.0)  # NaN for J <= 0, which the health check reports
        for i in range(3):
            for j in range(3):
                F[p, i, j] = r if i == j else 0.0


@njit(cache=True)
def _stress_from_F(F, tau, E):
    """tau_p = E (J_p - 1) I with J_p = det F_p; F, tau (n, d, d)."""
    d = F.shape[1]
    for p in range(F.shape[0]):
        s = E * (volume_ratio(F, p) - 1.0)
        for i in range(d):
            for j in range(d):
                tau[p, i, j] = s if i == j else 0.0


@njit(cache=True, inline="always")
def _psi(J, E):
    """Energy density E (J - 1 - ln J)."""
    return E * (J - 1.0 - math.log(J))


@njit(cache=True)
def _stress_from_J(J, tau, E):
    """tau_p = E (J_p - 1) I from the volume ratio alone; J (n,), tau (n, d, d)."""
    three = tau.shape[1] == 3
    for p in range(J.shape[0]):
        # Written out: loops over a run-time d are not unrolled, and this pass is the whole
        # constitutive cost of a fluid scene.
        s = E * (J[p] - 1.0)
        tau[p, 0, 0] = s
        tau[p, 0, 1] = 0.0
        tau[p, 1, 0] = 0.0
        tau[p, 1, 1] = s
        if three:
            tau[p, 0, 2] = 0.0
            tau[p, 1, 2] = 0.0
            tau[p, 2, 0] = 0.0
            tau[p, 2, 1] = 0.0
            tau[p, 2, 2] = s


@njit(cache=True)
def _energy_from_J(J, vol0, E):
    total = 0.0
    for p in range(J.shape[0]):
        total += vol0[p] * _psi(J[p], E)
    return total


@njit(cache=True)
def _energy_2d(F, vol0, E):
    total = 0.0
    for p in range(F.shape[0]):
        J = det2(load2(F, p))
        total += vol0[p] * _psi(J, E)
    return total


@njit(cache=True)
def _energy_3d(F, vol0, E):
    total = 0.0
    for p in range(F.shape[0]):
        J = det3(load3(F, p))
        total += vol0[p] * _psi(J, E)
    return total


class WeaklyCompressible(Material):
    """mpm88's J-based fluid with an energy; E is the bulk modulus (no nu: no shear)."""

    name = "weakly_compressible"
    parameters = {"E": Param(0.0, math.inf, doc="bulk modulus (stress units); tau = E (J - 1) I")}
    fields = {}
    deformation = "J"
    implicit = True

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        # Small-strain response tau = E tr(eps) I: lam = E, mu = 0, wave speed sqrt(E / rho).
        self.mu, self.lam = 0.0, self.params["E"]
        self._forget_shear = _forget_shear_2d if dim == 2 else _forget_shear_3d
        self._energy = _energy_2d if dim == 2 else _energy_3d

    def averages_volume(self, deformation: str) -> bool:
        """When its particles carry J: mode J, or mode L (the velocity gradient advances J);
        not mode F, where it carries F = J^(1/d) I beside an F-based material."""
        return deformation in ("J", "L")

    def updates_state(self, deformation: str) -> bool:
        """Only where the scene carries F (mode "F"): the return map resets it, and a J-only
        scene has nothing to project."""
        return deformation == "F"

    def return_map(self, fields, dt: float) -> None:
        """In a scene that carries F, reset F to J^(1/d) I after G2P advanced it."""
        if "F" in fields:
            self._forget_shear(fields["F"])

    def update_stress(self, fields, dt: float) -> None:
        """Writes fields["tau"] (n, d, d) from fields["J"] (n,) when the scene carries J
        alone, else from fields["F"] (n, d, d) = J^(1/d) I."""
        if "F" in fields:
            _stress_from_F(fields["F"], fields["tau"], self.params["E"])
        else:
            _stress_from_J(fields["J"], fields["tau"], self.params["E"])

    def _volume_ratio(self, fields) -> np.ndarray:
        """J^n (n,): the stored J, or det F when the scene carries F."""
        return np.linalg.det(fields["F"]) if "F" in fields else fields["J"]

    def implicit_energy(self, fields, L, dt: float) -> float:
        """sum_p V0 E (J_hat - 1 - ln J_hat), J_hat = det(I + dt L_p) J_p^n; +inf if a
        J_hat <= 0 (`hpcmpm.materials.implicit`)."""
        return float(j_energy(EYE[self.dim], self._volume_ratio(fields), fields["vol0"], L, dt,
                              self.params["E"]))

    def implicit_gradient(self, fields, L, dt: float, G) -> None:
        """Writes G (n, d, d), G_p = dt V0 E (J_hat - 1) (I + dt L_p)^-T."""
        j_gradient(EYE[self.dim], self._volume_ratio(fields), fields["vol0"], L, dt,
                   self.params["E"], G)

    def implicit_hessian(self, fields, L, dt: float, dL, dG) -> None:
        """Writes dG (n, d, d), dG_p = D^2 e_p(L_p)[dL_p]."""
        j_hessian(EYE[self.dim], self._volume_ratio(fields), fields["vol0"], L, dt,
                  self.params["E"], dL, dG)

    def energy(self, fields) -> float:
        """sum_p vol0_p E (J_p - 1 - ln J_p)."""
        if "F" in fields:
            return float(self._energy(fields["F"], fields["vol0"], self.params["E"]))
        return float(_energy_from_J(fields["J"], fields["vol0"], self.params["E"]))

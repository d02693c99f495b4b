"""A minimal L-form elastic material for the semi-implicit solver's tests (numpy, 2D and 3D),
independent of the production materials: compressible Neo-Hookean in F (Bonet & Wood 2008),

    psi(F) = mu/2 (tr F^T F - d) - mu ln J + lam/2 (ln J)^2,  P = mu (F - F^-T) + lam ln J F^-T,

written as a function of the step's velocity gradient with F^n held fixed (000 eq. 5.12):
F_hat = (I + dt L) F^n, e(L) = V0 psi(F_hat), de/dL = dt V0 P(F_hat) F^n^T,
D^2 e[dL] = dt^2 V0 dP(F_hat)[dL F^n] F^n^T with
dP[dF] = mu dF + (mu - lam ln J) F^-T dF^T F^-T + lam tr(F^-1 dF) F^-T.

`registered()` adds it to the material registry as ``type = "test_neo_hookean"`` for the
duration of a ``with`` block (a module-level fixture in the tests), so no other test sees it.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from hpcmpm.materials import MATERIALS
from hpcmpm.materials.base import Material
from hpcmpm.materials.params import POISSON, YOUNG, lame


def _psi(F, mu, lam):
    J = np.linalg.det(F)
    d = F.shape[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        lnJ = np.log(J)
    return 0.5 * mu * (np.einsum("pij,pij->p", F, F) - d) - mu * lnJ + 0.5 * lam * lnJ ** 2, J


def _piola(F, mu, lam):
    Fit = np.linalg.inv(F).transpose(0, 2, 1)
    lnJ = np.log(np.linalg.det(F))
    return mu * (F - Fit) + lam * lnJ[:, None, None] * Fit


def _dpiola(F, dF, mu, lam):
    Fi = np.linalg.inv(F)
    Fit = Fi.transpose(0, 2, 1)
    lnJ = np.log(np.linalg.det(F))
    a = (mu - lam * lnJ)[:, None, None]
    tr = np.einsum("pij,pji->p", Fi, dF)
    return mu * dF + a * Fit @ dF.transpose(0, 2, 1) @ Fit + lam * tr[:, None, None] * Fit


class NeoHookeanForTests(Material):
    name = "test_neo_hookean"
    parameters = {"E": YOUNG, "nu": POISSON}
    deformation = "F"
    implicit = True

    def __init__(self, spec, dim):
        super().__init__(spec, dim)
        self.mu, self.lam = lame(self.params["E"], self.params["nu"])

    def _hat(self, fields, L, dt):
        d = self.dim
        return (np.eye(d) + dt * L) @ fields["F"]

    def update_stress(self, fields, dt):
        F = fields["F"]
        fields["tau"][:] = _piola(F, self.mu, self.lam) @ F.transpose(0, 2, 1)

    def energy(self, fields):
        psi, _ = _psi(fields["F"], self.mu, self.lam)
        return float(np.sum(fields["vol0"] * psi))

    def implicit_energy(self, fields, L, dt):
        psi, J = _psi(self._hat(fields, L, dt), self.mu, self.lam)
        if np.any(~(J > 0.0)):
            return math.inf
        return float(np.sum(fields["vol0"] * psi))

    def implicit_gradient(self, fields, L, dt, G):
        Fn = fields["F"]
        P = _piola(self._hat(fields, L, dt), self.mu, self.lam)
        G[:] = dt * fields["vol0"][:, None, None] * P @ Fn.transpose(0, 2, 1)

    def implicit_hessian(self, fields, L, dt, dL, dG):
        Fn = fields["F"]
        dP = _dpiola(self._hat(fields, L, dt), dt * dL @ Fn, self.mu, self.lam)
        dG[:] = dt * fields["vol0"][:, None, None] * dP @ Fn.transpose(0, 2, 1)


@contextlib.contextmanager
def registered():
    """The test material in `MATERIALS` inside the block only."""
    MATERIALS[NeoHookeanForTests.name] = NeoHookeanForTests
    try:
        yield NeoHookeanForTests
    finally:
        MATERIALS.pop(NeoHookeanForTests.name, None)

"""Linear peridynamic solid (LPS; Silling, Epton, Weckner, Xu & Askari 2007), any Poisson ratio.

The base of 003 eq. 5.15-5.20 (which are garbled; the issue gives the model). With
w = omega beta (families.py), e = |Y| - |X| and d the dimension:

    m_p     = sum_q w |X|^2 V_q                     (reference, over the bonds at set-up)
    theta_p = (d / m_p) sum_q w |X| e V_q            (intact bonds)
    e^d     = e - theta_p |X| / d
    t_p     = (d kappa theta_p / m_p) |X| + alpha_p e^d,  alpha = 15 mu/m (3D), 8 mu/m (2D)
    f_p     = sum_q w (t_p + t_q) V_p V_q Y/|Y|
    W_p     = kappa theta_p^2 / 2 + (alpha_p / 2) sum_q w (e^d)^2 V_q

so an isotropic stretch s gives theta = d s, e^d = 0 and W = 9 K s^2/2 (3D), 2 kappa s^2 (2D)
for any family. Two passes: `lps_dilatation` (failure, theta) on owners, then the caller
refreshes theta (and m, once) in the halo, then `lps_forces`. m is fixed at set-up as in
Peridigm and LAMMPS (broken bonds lower theta through their absence, not m).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .geometry import bond_vectors, norm3


@njit(cache=True, error_model="numpy")
def lps_weighted_volume(x0, vol, offsets, slot, status, weight, n_owned, m):
    """m_p = sum_q w |X|^2 V_q over intact bonds."""
    dim = x0.shape[1]
    for p in range(n_owned):
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            d2 = 0.0
            for a in range(dim):
                t = x0[q, a] - x0[p, a]
                d2 += t * t
            s += weight[b] * d2 * vol[q]
        m[p] = s


@njit(cache=True, error_model="numpy")
def lps_dilatation(x, x0, vol, offsets, slot, status, weight, m, s0, n_owned, theta):
    """Failure (stretch > s0 breaks) then theta_p = (d/m_p) sum_q w |X| e V_q. Returns the
    number of half-bonds broken."""
    dim = x.shape[1]
    broken = 0
    for p in range(n_owned):
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            if q < 0:               # partner beyond the halo reach (pmb.py)
                status[b] = 0
                broken += 1
                continue
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            xl = norm3(X0, X1, X2)
            e = norm3(y0, y1, y2) - xl
            if e / xl > s0:
                status[b] = 0
                broken += 1
                continue
            s += weight[b] * xl * e * vol[q]
        theta[p] = dim * s / m[p] if m[p] > 0.0 else 0.0
    return broken


@njit(cache=True, error_model="numpy")
def _scalar_force(theta, m, e, xl, kappa, alpha_m, dim):
    """t of one end (without w): (d kappa theta/m)|X| + (alpha_m/m) (e - theta |X|/d)."""
    if m <= 0.0:
        return 0.0
    return (dim * kappa * theta / m) * xl + (alpha_m / m) * (e - theta * xl / dim)


@njit(cache=True, error_model="numpy")
def _pair(x, x0, vol, p, q, dim, w, m, theta, kappa, alpha_m):
    """(a, Y): the force on p from the bond p-q is a Y; t_p + t_q is symmetric in p, q."""
    y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
    xl = norm3(X0, X1, X2)
    yl = norm3(y0, y1, y2)
    e = yl - xl
    t = (_scalar_force(theta[p], m[p], e, xl, kappa, alpha_m, dim)
         + _scalar_force(theta[q], m[q], e, xl, kappa, alpha_m, dim))
    return w * t * (vol[p] * vol[q]) / yl, y0, y1, y2


@njit(cache=True, error_model="numpy")
def lps_bond_forces(x, x0, vol, offsets, slot, status, weight, m, theta, kappa, mu, n_owned,
                    out):
    """The per-half-bond terms of `lps_forces`, out (nb, d) (verification)."""
    dim = x.shape[1]
    alpha_m = (15.0 if dim == 3 else 8.0) * mu
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            for i in range(dim):
                out[b, i] = 0.0
            if status[b] == 0:
                continue
            a, y0, y1, y2 = _pair(x, x0, vol, p, slot[b], dim, weight[b], m, theta, kappa,
                                  alpha_m)
            out[b, 0] = a * y0
            out[b, 1] = a * y1
            if dim == 3:
                out[b, 2] = a * y2


@njit(cache=True, error_model="numpy")
def lps_forces(x, x0, vol, offsets, slot, status, weight, m, theta, kappa, mu, n_owned, f):
    """f_p = sum_q w (t_p + t_q) V_p V_q Y/|Y| over intact bonds; m, theta of owned + halo."""
    dim = x.shape[1]
    alpha_m = (15.0 if dim == 3 else 8.0) * mu
    for p in range(n_owned):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            a, y0, y1, y2 = _pair(x, x0, vol, p, slot[b], dim, weight[b], m, theta, kappa,
                                  alpha_m)
            f0 += a * y0
            f1 += a * y1
            f2 += a * y2
        f[p, 0] = f0
        f[p, 1] = f1
        if dim == 3:
            f[p, 2] = f2


@njit(cache=True, error_model="numpy")
def lps_energy_density(x, x0, vol, offsets, slot, status, weight, m, theta, kappa, mu,
                       n_owned, out):
    """W_p = kappa theta^2/2 + (alpha/2) sum_q w (e^d)^2 V_q."""
    dim = x.shape[1]
    alpha_m = (15.0 if dim == 3 else 8.0) * mu
    for p in range(n_owned):
        s = 0.0
        th = theta[p]
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            xl = norm3(X0, X1, X2)
            ed = (norm3(y0, y1, y2) - xl) - th * xl / dim
            s += weight[b] * ed * ed * vol[q]
        out[p] = 0.5 * kappa * th * th + (0.5 * alpha_m / m[p] * s if m[p] > 0.0 else 0.0)


class LPS:
    """LPS model over a points view (integrator.PDPoints): the weighted volume m is a
    persistent per-particle field (``pts.fields["m"]``, computed at set-up, moves with its
    particle, shipped once per halo build); theta is recomputed each step and refreshed in the
    halo (`halo_fields`).

    Parameters
    ----------
    bulk : K (3D) or kappa (2D).
    mu : shear modulus.
    critical_stretch : s0 (inf: no failure).
    time_step_c : micromodulus of the PMB solid with the same P-wave modulus.
    """

    name = "lps"
    persistent_fields = ("m",)
    halo_fields = ("theta",)

    def __init__(self, bulk: float, mu: float, critical_stretch: float = math.inf,
                 time_step_c: float = 0.0):
        self.kappa = float(bulk)
        self.mu = float(mu)
        self.s0 = float(critical_stretch)
        self.c_dt = float(time_step_c)
        self.theta = np.empty(0)

    def time_step_micromodulus(self) -> float:
        return self.c_dt

    def setup(self, pts) -> None:
        """m over the current intact bonds of the owners (halo rows: the caller fills them)."""
        m = pts.fields.setdefault("m", np.zeros(len(pts.x)))
        b = pts.bonds
        lps_weighted_volume(pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                            pts.n_owned, m)
        self.resize(len(pts.x))

    def resize(self, n: int) -> None:
        """Scratch for n owned + halo points."""
        if len(self.theta) != n:
            self.theta = np.zeros(n)

    def update_state(self, pts) -> int:
        b = pts.bonds
        return lps_dilatation(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                              pts.fields["m"], self.s0, pts.n_owned, self.theta)

    def forces(self, pts, f) -> int:
        b = pts.bonds
        lps_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                   pts.fields["m"], self.theta, self.kappa, self.mu, pts.n_owned, f)
        return 0

    def energy_density(self, pts, out=None) -> np.ndarray:
        b = pts.bonds
        out = np.empty(pts.n_owned) if out is None else out
        lps_energy_density(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                           pts.fields["m"], self.theta, self.kappa, self.mu, pts.n_owned, out)
        return out

    def strain_energy(self, pts) -> float:
        """sum_p V_p W_p over the owned points at their current positions, theta recomputed
        into scratch (the model's own theta, that of the last force pass, is left alone).
        Reads the intact bonds of ``pts`` as they are (the caller breaks the over-stretched
        ones on a copy first)."""
        b = pts.bonds
        theta = np.zeros(len(pts.x))
        lps_dilatation(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                       pts.fields["m"], math.inf, pts.n_owned, theta)
        out = np.empty(pts.n_owned)
        lps_energy_density(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                           pts.fields["m"], theta, self.kappa, self.mu, pts.n_owned, out)
        return float(np.dot(pts.vol[: pts.n_owned], out))

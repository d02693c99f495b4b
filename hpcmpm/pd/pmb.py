"""Prototype microelastic brittle (PMB) bond-based peridynamics (Silling & Askari 2005).

003 eq. 4.2-4.3 as corrected by the issue: s = (|Y| - |X|)/|X| (eq. 4.2 prints
"(||Y - X|| - X)/X"), pair force density on p  c s Y/|Y|, Y = x_q - x_p (eq. 4.3 prints a minus
sign and reuses K for the micromodulus). With the influence weight and partial volume w_pq
(families.py), the force on particle p in force units (003 eq. 4.1 times V_p) is

    f_p = sum_q c s w_pq V_p V_q Y/|Y|,

and the strain energy density W_p = 1/4 sum_q c w_pq s^2 |X| V_q (half of each pair's
micropotential c s^2 |X| / 2). Failure (003 eq. 4.8) is tested in the force loop before the
bond's force, so a bond that first exceeds s0 carries no force in that step, and both ends
decide from bitwise equal stretches (geometry.py). An intact bond whose partner is not in the
halo (slot -1) has stretched past the halo's reach and breaks (hpcmpm/parallel/pd_halo.py).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .geometry import bond_vectors, norm3


@njit(cache=True, error_model="numpy")
def _pair(x, x0, vol, p, q, dim, c, w):
    """(a, y0, y1, y2, s): the force on p from the bond is a * Y."""
    y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
    yl = norm3(y0, y1, y2)
    xl = norm3(X0, X1, X2)
    s = (yl - xl) / xl
    return c * s * w * (vol[p] * vol[q]) / yl, y0, y1, y2, s


@njit(cache=True, error_model="numpy")
def pmb_forces(x, x0, vol, offsets, slot, status, weight, c, s0, n_owned, f):
    """Failure then bond forces of the owned points. Writes f (n_owned, d); returns the number
    of half-bonds broken this call."""
    dim = x.shape[1]
    broken = 0
    for p in range(n_owned):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            if slot[b] < 0:
                # Partner outside the halo: stretched past the halo reach (halo.py), which
                # breaks at any rank count.
                status[b] = 0
                broken += 1
                continue
            a, y0, y1, y2, s = _pair(x, x0, vol, p, slot[b], dim, c, weight[b])
            if s > s0:
                status[b] = 0
                broken += 1
                continue
            f0 += a * y0
            f1 += a * y1
            f2 += a * y2
        f[p, 0] = f0
        f[p, 1] = f1
        if dim == 3:
            f[p, 2] = f2
    return broken


@njit(cache=True, error_model="numpy")
def pmb_bond_forces(x, x0, vol, offsets, slot, status, weight, c, n_owned, out):
    """Force on the owner of each intact half-bond (0 for broken ones), out (nb, d): the
    per-bond terms `pmb_forces` sums (verification of exact cancellation and plane fluxes)."""
    dim = x.shape[1]
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            for a in range(dim):
                out[b, a] = 0.0
            if status[b] == 0:
                continue
            a_, y0, y1, y2, s = _pair(x, x0, vol, p, slot[b], dim, c, weight[b])
            out[b, 0] = a_ * y0
            out[b, 1] = a_ * y1
            if dim == 3:
                out[b, 2] = a_ * y2


@njit(cache=True, error_model="numpy")
def pmb_energy_density(x, x0, offsets, slot, status, weight, vol, c, n_owned, out):
    """W_p = 1/4 sum_q c w s^2 |X| V_q over intact bonds (energy per volume)."""
    dim = x.shape[1]
    for p in range(n_owned):
        e = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            xl = norm3(X0, X1, X2)
            s = (norm3(y0, y1, y2) - xl) / xl
            e += c * weight[b] * s * s * xl * vol[q]
        out[p] = 0.25 * e


class PMB:
    """PMB model over a points view (see integrator.PDPoints).

    Parameters
    ----------
    c : micromodulus (moduli.pmb_micromodulus).
    critical_stretch : s0 (inf: no failure).
    """

    name = "pmb"
    persistent_fields: tuple[str, ...] = ()
    halo_fields: tuple[str, ...] = ()

    def __init__(self, c: float, critical_stretch: float = math.inf):
        self.c = float(c)
        self.s0 = float(critical_stretch)

    def time_step_micromodulus(self) -> float:
        return self.c

    def setup(self, pts) -> None:
        pass

    def resize(self, n: int) -> None:
        pass

    def update_state(self, pts) -> int:
        """Nothing before the forces: PMB tests failure in the force loop."""
        return 0

    def forces(self, pts, f) -> int:
        b = pts.bonds
        return pmb_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                          self.c, self.s0, pts.n_owned, f)

    def energy_density(self, pts, out=None) -> np.ndarray:
        b = pts.bonds
        out = np.empty(pts.n_owned) if out is None else out
        pmb_energy_density(pts.x, pts.x0, b.offsets, b.slot, b.status, b.weight, pts.vol,
                           self.c, pts.n_owned, out)
        return out

    def strain_energy(self, pts) -> float:
        """sum_p V_p W_p over the owned points: each intact bond's micropotential once (half
        at each end). Reads the intact bonds of ``pts`` as they are (the caller breaks the
        over-stretched ones on a copy first, `PDExtension.strain_energy`)."""
        return float(np.dot(pts.vol[: pts.n_owned], self.energy_density(pts)))

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

The clamp at sticky walls (clamp.py; integral-based bodies): a particle within a horizon of
such a wall is also bonded to the mirror images q' of itself and of its intact partners,
with the same pair force c s w' V_p V_q Y'/|Y'| on the ghost bond's Y', X' (the bond force
needs no state, so the ghost needs none either), and W_p counts those bonds as its own.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clamp import NO_CLAMP, NO_FACES, ghost_family, ghost_scratch, near_a_face
from .geometry import bond_vectors, norm3, stretched_past


@njit(cache=True, error_model="numpy")
def _pair(x, x0, vol, p, q, dim, c, w):
    """(a, y0, y1, y2, e, xl): the force on p from the bond is a * Y, with
    a = c s w V_p V_q / |Y| = c w V_p V_q e / (|X| |Y|), e = |Y| - |X|: one division a bond
    (the stretch's and the unit vector's in one; they bound the loop's speed)."""
    y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
    yl = norm3(y0, y1, y2)
    xl = norm3(X0, X1, X2)
    e = yl - xl
    return c * w * (vol[p] * vol[q]) * e / (xl * yl), y0, y1, y2, e, xl


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
            a, y0, y1, y2, e, xl = _pair(x, x0, vol, p, slot[b], dim, c, weight[b])
            if stretched_past(e, xl, s0):
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
            a_, y0, y1, y2, _, _ = _pair(x, x0, vol, p, slot[b], dim, c, weight[b])
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


@njit(cache=True, error_model="numpy")
def pmb_clamp_terms(x, x0, vol, offsets, slot, status, c, n_owned, faces, clamp, f, energy):
    """Add the clamp's ghost bonds (module docstring) of the owned points within reach of a
    face in ``faces`` (nf, 2): their forces to f (n_owned, d), or with ``energy`` their
    1/4 c w' s^2 |X'| V_q to f[:, 0] (the energy density of `pmb_energy_density`)."""
    dim = x.shape[1]
    GX, GY, GW, GQ = ghost_scratch(offsets, faces)
    for p in range(n_owned):
        if not near_a_face(x0, p, faces, clamp):
            continue
        for fc in range(faces.shape[0]):
            ng = ghost_family(x, x0, offsets, slot, status, p, int(faces[fc, 0]),
                              faces[fc, 1], clamp, GX, GY, GW, GQ)
            for g in range(ng):
                xl = norm3(GX[g, 0], GX[g, 1], GX[g, 2])
                yl = norm3(GY[g, 0], GY[g, 1], GY[g, 2])
                s = (yl - xl) / xl
                if energy:
                    f[p, 0] += 0.25 * c * GW[g] * s * s * xl * vol[GQ[g]]
                    continue
                a = c * s * GW[g] * (vol[p] * vol[GQ[g]]) / yl
                for i in range(dim):
                    f[p, i] += a * GY[g, i]


class PMB:
    """PMB model over a points view (see integrator.PDPoints).

    Parameters
    ----------
    c : micromodulus (moduli.pmb_micromodulus).
    critical_stretch : s0 (inf: no failure).
    clamp_faces, clamp : the sticky walls, (axis, plane) rows, and the `clamp.clamp_parameters`
        of the ghost bonds that clamp the body there (clamp.py; default: no clamp).
    """

    name = "pmb"
    persistent_fields: tuple[str, ...] = ()
    halo_fields: tuple[str, ...] = ()

    def __init__(self, c: float, critical_stretch: float = math.inf, clamp_faces=NO_FACES,
                 clamp=NO_CLAMP):
        self.c = float(c)
        self.s0 = float(critical_stretch)
        self.clamp_faces = np.ascontiguousarray(clamp_faces, dtype=np.float64)
        self.clamp = np.ascontiguousarray(clamp, dtype=np.float64)

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
        broken = pmb_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                            self.c, self.s0, pts.n_owned, f)
        if len(self.clamp_faces):       # after failure: a ghost is intact while its source is
            pmb_clamp_terms(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, self.c,
                            pts.n_owned, self.clamp_faces, self.clamp, f, False)
        return broken

    def energy_density(self, pts, out=None) -> np.ndarray:
        b = pts.bonds
        out = np.empty(pts.n_owned) if out is None else out
        pmb_energy_density(pts.x, pts.x0, b.offsets, b.slot, b.status, b.weight, pts.vol,
                           self.c, pts.n_owned, out)
        if len(self.clamp_faces):
            pmb_clamp_terms(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, self.c,
                            pts.n_owned, self.clamp_faces, self.clamp, out.reshape(-1, 1), True)
        return out

    def strain_energy(self, pts) -> float:
        """sum_p V_p W_p over the owned points: each intact bond's micropotential once (half
        at each end). Reads the intact bonds of ``pts`` as they are (the caller breaks the
        over-stretched ones on a copy first, `PDExtension.strain_energy`)."""
        return float(np.dot(pts.vol[: pts.n_owned], self.energy_density(pts)))

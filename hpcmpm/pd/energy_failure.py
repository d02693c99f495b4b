"""Energy failure of peridynamic bonds in SPB-MPM (003 eq. 6.11-6.13, as corrected in issue 11).

Per intact bond p-q, with the correspondence force states (correspondence.py, A = P K^-1 of
each end, w = omega beta the bond weight) the bond force per V_p V_q is

    T_p<X> - T_q<-X> = w (A_p + A_q) X

and its energy density (per V_p V_q) is either

    W = (T_p<X> - T_q<-X>) . U,   U = Y - X                 failure = "energy" (eq. 6.11, as
                                                             printed)
    W = int (T_p<X> - T_q<-X>) . dY                          failure = "work" (Foster et al.
                                                             2011; trapezoidal along the steps)

A bond breaks (omega = 0 from the next evaluation on, eq. 6.13; irreversible) when W > beta W_c,

    W_c = 3 G_c / (2 h delta^3)   (2D, thickness h)          (eq. 6.12 with l0 = delta)
    W_c = 4 G_c / (pi delta^4)    (3D)

which is the energy density at which every bond crossing a unit area, each storing W_c V_p
V_q, holds G_c in a continuum family. beta is the bond's partial-volume fraction (families.py):
a bond at the horizon edge carries beta of a full bond's force and so of its energy, and
breaks at the same density as a full one. With it the lattice sum over the bonds crossing a
plane is 1.022 G_c (3D) / 0.991 G_c (2D) at delta = 3.015 spacings (tests/verification/
test_spb_failure.py); those are the issue's figures, which the constant-energy bond of this
criterion reproduces (the PMB bond energy, proportional to |X|, does not).

A linear bond's work is half the printed product, so "work" breaks a linear bond at sqrt(2)
times the strain of "energy". A bond created between already deformed particles (an MPM
particle converting next to PD ones) starts its work at half the printed product, the work a
linear bond would have stored on the way.

Both ends of a bond compute W bitwise equal (negations are exact, sums commute: geometry.py),
so both break it in the same step on any rank count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .families import partial_volume
from .geometry import bond_vectors, norm3

FAILURES = ("energy", "work", "stretch")
WORK_STATE = ("work", "y0", "y1", "y2", "t0", "t1", "t2")


def critical_bond_energy(dim: int, G_c: float, delta: float, thickness: float = 1.0) -> float:
    """W_c of eq. 6.12 (l0 = delta)."""
    if dim == 2:
        return 3.0 * G_c / (2.0 * thickness * delta ** 3)
    return 4.0 * G_c / (math.pi * delta ** 4)


@njit(cache=True, error_model="numpy")
def energy_failure(x, x0, offsets, slot, status, weight, A, n_owned, Wc, delta, spacing,
                   partial_volumes, work_form, work, y0, y1, y2, t0, t1, t2):
    """Break the intact bonds of the owned points whose energy W exceeds beta W_c (module
    docstring). ``A`` (owned + halo, d, d) from `correspondence_force_state`; ``Wc`` (owned +
    halo,) the critical energy of each point's material (a bond between two materials takes
    the smaller, the same at both ends); the work arrays
    (nb,) are used only when ``work_form`` (the previous Y and bond force per half-bond, and
    the accumulated work). Returns (half-bonds broken, smallest |W - beta W_c| / (beta W_c)
    over the bonds tested)."""
    dim = x.shape[1]
    broken = 0
    margin = np.inf
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            Y0, Y1, Y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            w = weight[b]
            T0 = 0.0
            T1 = 0.0
            T2 = 0.0
            for j in range(dim):
                Xj = X0 if j == 0 else (X1 if j == 1 else X2)
                T0 += (A[p, 0, j] + A[q, 0, j]) * Xj
                T1 += (A[p, 1, j] + A[q, 1, j]) * Xj
                if dim == 3:
                    T2 += (A[p, 2, j] + A[q, 2, j]) * Xj
            T0 *= w
            T1 *= w
            T2 *= w
            if work_form:
                if y0[b] == 0.0 and y1[b] == 0.0 and y2[b] == 0.0:
                    # First evaluation of this bond: the work a linear bond stored so far.
                    W = 0.5 * (T0 * (Y0 - X0) + T1 * (Y1 - X1) + T2 * (Y2 - X2))
                else:
                    W = work[b] + 0.5 * ((T0 + t0[b]) * (Y0 - y0[b]) + (T1 + t1[b]) * (Y1 - y1[b])
                                         + (T2 + t2[b]) * (Y2 - y2[b]))
                work[b] = W
                y0[b], y1[b], y2[b] = Y0, Y1, Y2
                t0[b], t1[b], t2[b] = T0, T1, T2
            else:
                W = T0 * (Y0 - X0) + T1 * (Y1 - X1) + T2 * (Y2 - X2)
            limit = partial_volume(norm3(X0, X1, X2), delta, spacing, partial_volumes) * \
                min(Wc[p], Wc[q])
            margin = min(margin, abs(W - limit) / limit)
            if W > limit:
                status[b] = 0
                broken += 1
    return broken, margin

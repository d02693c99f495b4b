"""Peridynamic constants from engineering moduli: micromodulus, critical stretch, time step.

PMB micromodulus (Silling & Askari 2005; 003 eq. 4.3 prints "K = 18K/(pi l^4)", a symbol
clash): the pair force density on p is c s omega Y/|Y| with s = (|Y| - |X|)/|X|. Matching
the strain energy density of an isotropic expansion (9 K s^2 / 2 in 3D, 2 kappa s^2 in 2D) in a
full continuum family gives, with I_k = int_0^delta omega(r) r^k dr,

    3D:  c = 9 K / (2 pi I_3)           constant omega: c = 18 K / (pi delta^4)
    2D:  c = 4 kappa / (pi h I_2)       constant omega: c = 12 kappa / (pi h delta^3)

and kappa = E / (2 (1 - nu)) with nu = 1/3 (plane stress: c = 9E/(pi h delta^3)) or
kappa = lambda + mu with nu = 1/4 (plane strain: c = 48E/(5 pi h delta^3)); in 3D nu = 1/4,
K = E / (3 (1 - 2 nu)). These Poisson ratios are the only ones a pair potential represents.

Critical stretch from the fracture energy G0 (the work to break every bond crossing a unit
area, continuum family): G0 = pi c s0^2 I_4 / 2 (3D), G0 = c h s0^2 I_3 (2D), i.e. for a
constant omega s0 = sqrt(5 G0 / (9 K delta)) (3D), sqrt(4 pi G0 / (9 E delta)) (plane stress),
sqrt(5 pi G0 / (12 E delta)) (plane strain), the issue's formulas. State-based models use the
same s0 with their own K (3D) or E (2D).

Time step (Silling & Askari 2005 eq. 17): dt_p = sqrt(2 rho_p / sum_q V_q c w_pq / |X|);
state-based models use the c of a PMB solid with their P-wave modulus M (3D: K_pmb = 5M/9,
2D: kappa_pmb = 2M/3, since a PMB solid has M = 9K/5 in 3D and 3 kappa/2 in 2D).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .families import influence_moment

PLANES = ("strain", "stress")


def pmb_poisson(dim: int, plane: str = "strain") -> float:
    """The only Poisson ratio a PMB solid has."""
    if dim == 3:
        return 0.25
    if plane not in PLANES:
        raise ValueError(f"plane must be 'strain' or 'stress', got {plane!r}")
    return 0.25 if plane == "strain" else 1.0 / 3.0


def check_pmb_poisson(dim: int, nu: float, plane: str = "strain") -> str | None:
    """A problem line when ``nu`` is not the PMB's Poisson ratio, else None."""
    allowed = pmb_poisson(dim, plane)
    if abs(nu - allowed) > 1e-12:
        where = "3D" if dim == 3 else f"2D plane {plane}"
        return f"nu: a PMB solid in {where} has nu = {allowed:.6g}, got {nu:g}"
    return None


def bulk_modulus(dim: int, E: float, nu: float, plane: str = "strain") -> float:
    """K (3D) or the 2D bulk modulus kappa (plane strain: lambda + mu; stress: E/(2(1-nu)))."""
    if dim == 3:
        return E / (3.0 * (1.0 - 2.0 * nu))
    if plane == "stress":
        return E / (2.0 * (1.0 - nu))
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return lam + mu


def shear_modulus(E: float, nu: float) -> float:
    return E / (2.0 * (1.0 + nu))


def pmb_micromodulus(dim: int, bulk: float, delta: float, influence: str = "constant",
                     thickness: float = 1.0) -> float:
    """c from the bulk modulus K (3D) or kappa (2D) (module docstring)."""
    if dim == 3:
        return 9.0 * bulk / (2.0 * math.pi * influence_moment(influence, 3, delta))
    return 4.0 * bulk / (math.pi * thickness * influence_moment(influence, 2, delta))


def pmb_micromodulus_from_E(dim: int, E: float, nu: float, delta: float,
                            plane: str = "strain", influence: str = "constant",
                            thickness: float = 1.0) -> float:
    """c from (E, nu); raises ValueError naming the allowed nu when the PMB cannot
    represent ``nu``."""
    problem = check_pmb_poisson(dim, nu, plane)
    if problem:
        raise ValueError(problem)
    return pmb_micromodulus(dim, bulk_modulus(dim, E, nu, plane), delta, influence, thickness)


def equivalent_micromodulus(dim: int, bulk: float, mu: float, delta: float,
                            influence: str = "constant", thickness: float = 1.0) -> float:
    """c of the PMB solid with the same P-wave modulus (time step of state-based models)."""
    if dim == 3:
        return pmb_micromodulus(3, 5.0 * (bulk + 4.0 * mu / 3.0) / 9.0, delta, influence)
    return pmb_micromodulus(2, 2.0 * (bulk + mu) / 3.0, delta, influence, thickness)


def critical_stretch(dim: int, G0: float, c: float, delta: float,
                     influence: str = "constant", thickness: float = 1.0) -> float:
    """s0 from the fracture energy G0 for micromodulus c (module docstring)."""
    if G0 <= 0.0:
        raise ValueError(f"fracture_energy: must be > 0, got {G0:g}")
    if dim == 3:
        return math.sqrt(2.0 * G0 / (math.pi * c * influence_moment(influence, 4, delta)))
    return math.sqrt(G0 / (c * thickness * influence_moment(influence, 3, delta)))


def critical_stretch_from_moduli(dim: int, G0: float, E: float, nu: float, delta: float,
                                 plane: str = "strain") -> float:
    """The issue's closed forms for a constant influence function: sqrt(5 G0/(9 K delta))
    (3D), sqrt(4 pi G0/(9 E delta)) (plane stress), sqrt(5 pi G0/(12 E delta)) (plane
    strain)."""
    if G0 <= 0.0:
        raise ValueError(f"fracture_energy: must be > 0, got {G0:g}")
    if dim == 3:
        return math.sqrt(5.0 * G0 / (9.0 * bulk_modulus(3, E, nu) * delta))
    if plane == "stress":
        return math.sqrt(4.0 * math.pi * G0 / (9.0 * E * delta))
    return math.sqrt(5.0 * math.pi * G0 / (12.0 * E * delta))


@njit(cache=True, error_model="numpy")
def silling_askari_steps(x0, vol, rho, offsets, slot, status, weight, c, n_owned, out):
    """dt_p = sqrt(2 rho_p / sum_q V_q c w_pq / |X|) over intact bonds (Silling & Askari
    2005 eq. 17, without a safety factor); inf for a particle without bonds. Returns min."""
    dim = x0.shape[1]
    best = np.inf
    for p in range(n_owned):
        k = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            d2 = 0.0
            for a in range(dim):
                t = x0[q, a] - x0[p, a]
                d2 += t * t
            k += vol[q] * c * weight[b] / math.sqrt(d2)
        out[p] = math.sqrt(2.0 * rho[p] / k) if k > 0.0 else np.inf
        best = min(best, out[p])
    return best


def stable_time_step(x0, vol, rho, bonds, c, n_owned, safety: float = 0.8) -> float:
    """The issue's rule dt = safety * min_p sqrt(2 rho / sum_q V_q c / |X|)."""
    rho = np.broadcast_to(np.asarray(rho, dtype=np.float64), (len(vol),)).copy()
    out = np.empty(n_owned)
    return safety * silling_askari_steps(x0, vol, rho, bonds.offsets, bonds.slot,
                                         bonds.status, bonds.weight, c, n_owned, out)

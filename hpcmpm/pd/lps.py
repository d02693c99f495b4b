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

The clamp at sticky walls (clamp.py; integral-based bodies): a particle p within a horizon of
such a wall is also bonded to the mirror images q' of itself and of its intact partners. Its
m and theta sum over those ghost bonds too (the family of the body continued through the
wall). The ghost bond's force needs t_q', hence the ghost's dilatation theta_q', which the
odd extension u(X') = -u(R X') does not give from theta_q (a strain along the wall changes
sign in the image: linearized, theta_q' = 2 eps_nn - theta_q). It is summed exactly, over
the image of q's own family: q's intact bonds q-r seen from q' (X' = R X_qr,
Y' = R X_qr - (u_r - u_q)) and q's ghost bonds across the same wall seen from q' (the bond
from the real r to q': Y' = x_r - x_q'). So `lps_clamp_dilatation` stores theta' per
particle and wall (``theta_image``, refreshed in the halo with theta) and m_q' = m_q (the
image family is the mirror of q's). A corner's doubly reflected images are left out, as in
the correspondence clamp.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clamp import (NO_CLAMP, NO_FACES, ghost_family, ghost_scratch, ghost_stretch_sums,
                    near_a_face)
from .geometry import bond_vectors, norm3, stretched_past


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
            if stretched_past(e, xl, s0):
                status[b] = 0
                broken += 1
                continue
            s += weight[b] * xl * e * vol[q]
        theta[p] = dim * s / m[p] if m[p] > 0.0 else 0.0
    return broken


@njit(cache=True, inline="always")
def shear_coefficient(mu, dim):
    """alpha m = 15 mu (3D), 8 mu (2D) (Silling 2007: alpha = 15 mu/m; its 2D counterpart):
    the one definition every LPS kernel, clamped and viscoelastic ones included, uses."""
    return (15.0 if dim == 3 else 8.0) * mu


@njit(cache=True, error_model="numpy")
def _end_coefficients(theta, m, kappa, alpha_m, dim):
    """(g, k) of one end of a bond: its scalar force state (without w)
    t = (d kappa theta/m)|X| + (alpha_m/m) (e - theta |X|/d) = g |X| + k e, with
    g = d kappa theta/m - (alpha_m/m) theta/d and k = alpha_m/m; (0, 0) where m <= 0.
    Per point, not per bond: the bond loops then divide once a bond (by |Y|)."""
    if m <= 0.0:
        return 0.0, 0.0
    k = alpha_m / m
    return dim * kappa * theta / m - k * theta / dim, k


@njit(cache=True, error_model="numpy")
def end_coefficients(theta, m, kappa, alpha_m, dim):
    """`_end_coefficients` of every point (owned + halo rows): arrays (g, k)."""
    n = theta.shape[0]
    g = np.empty(n)
    k = np.empty(n)
    for p in range(n):
        g[p], k[p] = _end_coefficients(theta[p], m[p], kappa, alpha_m, dim)
    return g, k


@njit(cache=True, error_model="numpy")
def _pair(x, x0, vol, p, q, dim, w, g, k):
    """(a, Y): the force on p from the bond p-q is a Y, a = w (t_p + t_q) V_p V_q / |Y| with
    t_p + t_q = (g_p + g_q)|X| + (k_p + k_q) e (`_end_coefficients`), symmetric in p, q."""
    y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
    xl = norm3(X0, X1, X2)
    yl = norm3(y0, y1, y2)
    t = (g[p] + g[q]) * xl + (k[p] + k[q]) * (yl - xl)
    return w * t * (vol[p] * vol[q]) / yl, y0, y1, y2


@njit(cache=True, error_model="numpy")
def lps_bond_forces(x, x0, vol, offsets, slot, status, weight, m, theta, kappa, mu, n_owned,
                    out):
    """The per-half-bond terms of `lps_forces`, out (nb, d) (verification)."""
    dim = x.shape[1]
    g, k = end_coefficients(theta, m, kappa, shear_coefficient(mu, dim), dim)
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            for i in range(dim):
                out[b, i] = 0.0
            if status[b] == 0:
                continue
            a, y0, y1, y2 = _pair(x, x0, vol, p, slot[b], dim, weight[b], g, k)
            out[b, 0] = a * y0
            out[b, 1] = a * y1
            if dim == 3:
                out[b, 2] = a * y2


@njit(cache=True, error_model="numpy")
def lps_forces(x, x0, vol, offsets, slot, status, weight, m, theta, kappa, mu, n_owned, f):
    """f_p = sum_q w (t_p + t_q) V_p V_q Y/|Y| over intact bonds; m, theta of owned + halo."""
    dim = x.shape[1]
    g, k = end_coefficients(theta, m, kappa, shear_coefficient(mu, dim), dim)
    for p in range(n_owned):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            a, y0, y1, y2 = _pair(x, x0, vol, p, slot[b], dim, weight[b], g, k)
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
    alpha_m = shear_coefficient(mu, dim)
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


@njit(cache=True, error_model="numpy")
def lps_clamp_weighted_volume(x0, vol, offsets, slot, status, n_owned, faces, clamp, m):
    """m_p += sum over p's ghost bonds (clamp.py) of w' |X'|^2 V_q."""
    GX, GY, GW, GQ = ghost_scratch(offsets, faces)
    for p in range(n_owned):
        for fc in range(faces.shape[0]):
            ng = ghost_family(x0, x0, offsets, slot, status, p, int(faces[fc, 0]),
                              faces[fc, 1], clamp, GX, GY, GW, GQ)
            for g in range(ng):
                m[p] += GW[g] * (GX[g, 0] ** 2 + GX[g, 1] ** 2 + GX[g, 2] ** 2) * vol[GQ[g]]


@njit(cache=True, error_model="numpy")
def lps_clamp_dilatation(x, x0, vol, offsets, slot, status, weight, m, n_owned, faces, clamp,
                         theta, theta_image):
    """For the owned points within reach of a face: add their ghost bonds to theta (after
    `lps_dilatation`, so after failure), and theta_image[p, f], the dilatation of p's image
    across face f (module docstring; the sums: `clamp.ghost_stretch_sums`). theta_image is 0
    where p is out of reach of f."""
    dim = x.shape[1]
    ghosts = ghost_scratch(offsets, faces)
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        extra = 0.0
        unused = 0.0
        near = near_a_face(x0, p, faces, clamp)
        for fc in range(faces.shape[0]):
            theta_image[p, fc] = 0.0
            if m[p] <= 0.0 or not near:
                continue
            extra, unused, image, ng = ghost_stretch_sums(
                x, x0, vol, offsets, slot, status, weight, p, int(faces[fc, 0]), faces[fc, 1],
                clamp, ghosts, X, Y, extra, unused)
            if ng > 0:
                theta_image[p, fc] = dim * image / m[p]
        if m[p] > 0.0:
            theta[p] += dim * extra / m[p]


@njit(cache=True, error_model="numpy")
def lps_clamp_terms(x, x0, vol, offsets, slot, status, m, theta, theta_image, kappa, mu,
                    n_owned, faces, clamp, f, energy):
    """Add the ghost bonds of the owned points within reach of a face: the pair force
    w' (t_p + t_q') V_p V_q Y'/|Y'| (t_q' with theta_image[q, f] and m_q) to f (n_owned, d),
    or with ``energy`` their (alpha/2) w' (e^d)^2 V_q to f[:, 0] (`lps_energy_density`)."""
    dim = x.shape[1]
    alpha_m = shear_coefficient(mu, dim)
    GX, GY, GW, GQ = ghost_scratch(offsets, faces)
    for p in range(n_owned):
        if m[p] <= 0.0 or not near_a_face(x0, p, faces, clamp):
            continue
        for fc in range(faces.shape[0]):
            ng = ghost_family(x, x0, offsets, slot, status, p, int(faces[fc, 0]),
                              faces[fc, 1], clamp, GX, GY, GW, GQ)
            for g in range(ng):
                q = GQ[g]
                xl = norm3(GX[g, 0], GX[g, 1], GX[g, 2])
                yl = norm3(GY[g, 0], GY[g, 1], GY[g, 2])
                e = yl - xl
                if energy:
                    ed = e - theta[p] * xl / dim
                    f[p, 0] += 0.5 * alpha_m / m[p] * GW[g] * ed * ed * vol[q]
                    continue
                gp, kp = _end_coefficients(theta[p], m[p], kappa, alpha_m, dim)
                gq, kq = _end_coefficients(theta_image[q, fc], m[q], kappa, alpha_m, dim)
                t = (gp + gq) * xl + (kp + kq) * e
                a = GW[g] * t * (vol[p] * vol[q]) / yl
                for i in range(dim):
                    f[p, i] += a * GY[g, i]


class LPS:
    """LPS model over a points view (integrator.PDPoints): the weighted volume m is a
    persistent per-particle field (``pts.fields["m"]``, computed at set-up, moves with its
    particle, shipped once per halo build); theta is recomputed each step and refreshed in the
    halo (`halo_fields`), with the image dilatations ``theta_image`` where there is a clamp.

    Parameters
    ----------
    bulk : K (3D) or kappa (2D).
    mu : shear modulus.
    critical_stretch : s0 (inf: no failure).
    time_step_c : micromodulus of the PMB solid with the same P-wave modulus.
    clamp_faces, clamp : the sticky walls, (axis, plane) rows, and the `clamp.clamp_parameters`
        of the ghost bonds that clamp the body there (clamp.py; default: no clamp).
    """

    name = "lps"
    persistent_fields = ("m",)

    def __init__(self, bulk: float, mu: float, critical_stretch: float = math.inf,
                 time_step_c: float = 0.0, clamp_faces=NO_FACES, clamp=NO_CLAMP):
        self.kappa = float(bulk)
        self.mu = float(mu)
        self.s0 = float(critical_stretch)
        self.c_dt = float(time_step_c)
        self.clamp_faces = np.ascontiguousarray(clamp_faces, dtype=np.float64)
        self.clamp = np.ascontiguousarray(clamp, dtype=np.float64)
        self.halo_fields = ("theta", "theta_image") if len(self.clamp_faces) else ("theta",)
        self.theta = np.empty(0)
        self.theta_image = np.empty((0, len(self.clamp_faces)))

    def time_step_micromodulus(self) -> float:
        return self.c_dt

    def setup(self, pts) -> None:
        """m over the current intact bonds of the owners, ghost bonds included (halo rows: the
        caller fills them)."""
        m = pts.fields.setdefault("m", np.zeros(len(pts.x)))
        b = pts.bonds
        lps_weighted_volume(pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                            pts.n_owned, m)
        if len(self.clamp_faces):
            lps_clamp_weighted_volume(pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                      pts.n_owned, self.clamp_faces, self.clamp, m)
        self.resize(len(pts.x))

    def resize(self, n: int) -> None:
        """Scratch for n owned + halo points."""
        if len(self.theta) != n:
            self.theta = np.zeros(n)
            self.theta_image = np.zeros((n, len(self.clamp_faces)))

    def _dilatation(self, pts, s0, theta, theta_image) -> int:
        """Failure (stretch > s0) and theta of the owners, the clamp's ghost bonds included."""
        b = pts.bonds
        broken = lps_dilatation(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                                pts.fields["m"], s0, pts.n_owned, theta)
        if len(self.clamp_faces):
            lps_clamp_dilatation(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                 b.weight, pts.fields["m"], pts.n_owned, self.clamp_faces,
                                 self.clamp, theta, theta_image)
        return broken

    def update_state(self, pts) -> int:
        return self._dilatation(pts, self.s0, self.theta, self.theta_image)

    def forces(self, pts, f) -> int:
        b = pts.bonds
        lps_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                   pts.fields["m"], self.theta, self.kappa, self.mu, pts.n_owned, f)
        if len(self.clamp_faces):
            lps_clamp_terms(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                            pts.fields["m"], self.theta, self.theta_image, self.kappa,
                            self.mu, pts.n_owned, self.clamp_faces, self.clamp, f, False)
        return 0

    def _energy_density(self, pts, theta, out) -> np.ndarray:
        b = pts.bonds
        lps_energy_density(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                           pts.fields["m"], theta, self.kappa, self.mu, pts.n_owned, out)
        if len(self.clamp_faces):
            lps_clamp_terms(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                            pts.fields["m"], theta, self.theta_image, self.kappa, self.mu,
                            pts.n_owned, self.clamp_faces, self.clamp, out.reshape(-1, 1),
                            True)
        return out

    def energy_density(self, pts, out=None) -> np.ndarray:
        out = np.empty(pts.n_owned) if out is None else out
        return self._energy_density(pts, self.theta, out)

    def strain_energy(self, pts) -> float:
        """sum_p V_p W_p over the owned points at their current positions, theta recomputed
        into scratch (the model's own theta, that of the last force pass, is left alone).
        Reads the intact bonds of ``pts`` as they are (the caller breaks the over-stretched
        ones on a copy first)."""
        theta = np.zeros(len(pts.x))
        image = np.zeros((len(pts.x), len(self.clamp_faces)))
        self._dilatation(pts, math.inf, theta, image)
        out = self._energy_density(pts, theta, np.empty(pts.n_owned))
        return float(np.dot(pts.vol[: pts.n_owned], out))

"""Bond-energy elasticity with bond plasticity (003 eq. 5.5-5.11): ``model = "bond_energy"``.

Energy of a bond of p (eq. 5.5, with the issue's scale beta, which the thesis omits):

    psi = beta w (mu (|Ybar|/|X| - 1 - e_p)^2 + lambda/2 (|Y|/|X| - 1 - e_p)^2),  Ybar = F_p X
    W_p = sum_q psi V_q,    beta = d^2 K / ((2 mu + lambda) sum_q w V_q)  (full family)

with K = lambda + 2 mu/d, w = omega * (partial volume) and F_p the correspondence deformation
gradient (correspondence.py, eq. 4.4). beta makes an isotropic stretch s store d^2 K s^2/2
(9 K s^2/2 in 3D, 2 kappa s^2 in 2D) in a full family. The force state is dpsi/dY with Ybar
held fixed (eq. 5.6; its printed form 2 mu w/|X|^2 (Ybar - |X| dir Ybar) is this):

    T_p<X> = (beta w / |X|) [2 mu (|Ybar|/|X| - 1 - e_p) dir(Ybar) + lambda (|Y|/|X| - 1 - e_p) dir(Y)]

and f_p = sum_q (T_p<X> - T_q<-X>) V_p V_q. Under a small uniform strain Ybar = Y and this is
a central-force solid (nu_eff = 1/4, whatever lambda/mu), and the Ybar term is not the exact
gradient of sum_p V_p W_p (F_p depends on all of p's bonds): energy is not conserved exactly;
scripts/study_bond_energy.py measures both.

Bond plasticity (eq. 5.8-5.11 as corrected by the issue): with e = |Y|/|X| - 1, e_iso the
point's mean bond stretch and e_dev = e - e_iso,

    E_dev = (w beta (2 mu + lambda) / |X|) (e_dev - e_p),      f = E_dev^2 / 2 - psi_p  (5.10)
    f > 0:  de_p = |X| (E_dev - sqrt(2 psi_p) sign E_dev) / (w beta (2 mu + lambda))

(psi_p is ``plastic_yield``, or from ``plastic_yield_stretch`` by `yield_energy_of_stretch`),
which puts the bond exactly on f = 0 (eq. 5.11 divides by lambda instead of w (2 mu + lambda)
and does not return to the yield surface). A return that would lengthen the bond's elastic
stretch |e - e_p| is not taken (the bond stays outside the surface until the flow relaxes
it): e_dev is measured from the neighbours' mean stretch, not from the bond's own energy, so
such a return would store energy in the bond, negative plastic work. Without this guard a
perfectly plastic 16 x 16 block whose bonds fail (s0 = 0.02) gains 33 % kinetic energy;
with it, it loses 37 % (scripts/study_pd_models.py reports the elastic drift). e_iso = sum_q w |X| (|Y| - |X|) V_q / sum_q w |X|^2
V_q (the LPS dilatation over d; `bond_iso_stretches`) instead of the issue's J^{1/d} - 1 of
F_p: both are s for an isotropic stretch s and tr(eps)/d to first order, but once e_p has
absorbed the deviatoric stretch the bond force is ~ e_iso, and J of a disordered (plastically
flowed) family is unbounded: with J^{1/d} - 1 a perfectly plastic block gains energy without
bound (velocities x1e9 in 2500 steps), with the bond dilatation it dissipates. e_p is a per-bond state (``bonds.state["plastic
_stretch"]``) shared by both ends: e_iso is the mean of the two ends' J^{1/d} - 1, so both
ends update it identically and the pair forces stay bitwise antisymmetric; the thesis's
per-end e_p would need the other end's state. With ``plastic_yield`` set the force is eq.
5.9 as printed: eq. 5.8's |Ybar| - |X| ~ |Y| - |X| in the mu term (direction still Ybar),

    T_p<X> = (beta w / |X|) (e - e_p) [2 mu dir(Ybar) + lambda dir(Y)],

and psi = beta w (mu + lambda/2) (e - e_p)^2. Keeping |Ybar| there instead would leave
2 mu (|Ybar|/|X| - 1 - e_p) once e_p has absorbed the deviatoric part of e: a force of the
size of |Ybar| - |Y| that no plastic flow bounds, which drives crushed regions unstable.
Under a uniform deformation the two forms agree (Ybar = Y); psi_p = inf is eq. 5.6.

Passes: `correspondence_kinematics` (failure on the total stretch, K, F) on owners, the halo
refreshes F and ``active``, then `bond_energy_forces` (return map, forces). A detached point
(correspondence.py) has no Ybar term.

The clamp at sticky walls (clamp.py; integral-based bodies): K, F and e_iso of a particle
within reach of such a wall sum over its ghost bonds too, e_iso of the ghost q' is that of
q's image family (``eiso_image``, refreshed in the halo), F_q' = I - (F_q - I) R, and each
ghost bond returns and keeps its own plastic stretch (`bond_energy_clamp_terms`; the states
``mirror_plastic_stretch<f>`` of the clamp's ghost store, clamp.ghost_store, kept only for
the particles within reach of a clamped wall and only with psi_p finite). Ghost bonds do not
break and do not count in the damage or the crack planes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clamp import (NO_CLAMP, NO_FACES, attach_ghost_store, clamp_reach, ghost_arrays, ghost_at,
                    ghost_scratch, ghost_stretch_sums, near_a_face)
from .correspondence import correspondence_kinematics
from .families import full_family_sum
from .geometry import bond_vectors, norm3

PLASTIC_STATE = "plastic_stretch"
NO_STATE = np.zeros(0)      # the kernels' plastic stretch of an elastic body (never read)


def mirror_state_names(n_faces: int) -> tuple[str, ...]:
    """States of the clamp's ghost bonds (clamp.ghost_store), one per clamping face: the
    plastic stretch of the bond to the image of the particle or of a half-bond's partner."""
    return tuple(f"mirror_plastic_stretch{k}" for k in range(n_faces))


def bond_energy_scale(dim: int, lam: float, mu: float, family_sum: float) -> float:
    """beta = d^2 K / ((2 mu + lambda) sum_q w V_q), K = lambda + 2 mu / d."""
    bulk = lam + 2.0 * mu / dim
    return dim * dim * bulk / ((2.0 * mu + lam) * family_sum)


def yield_energy_of_stretch(scale: float, lam: float, mu: float, delta: float,
                            stretch: float) -> float:
    """psi_p (eq. 5.10) at which a bond of length ``delta`` (the horizon) and influence w = 1
    yields at the deviatoric stretch |e_dev - e_p| = ``stretch``: (beta (2 mu + lambda) s_y /
    delta)^2 / 2. A bond of length |X| and influence w then yields at s_y |X| / (w delta).
    At a horizon fixed in spacings psi_p scales as delta^-(2d + 2) (beta ~ delta^-d), so the
    same s_y is the same material at any dx (the yield pattern is scale free), where a fixed
    psi_p is not (its yield stretch grows as delta^(d + 1))."""
    return 0.5 * (scale * (2.0 * mu + lam) * stretch / delta) ** 2


def yield_stretch_of_energy(scale: float, lam: float, mu: float, delta: float,
                            psi_p: float) -> float:
    """The s_y of `yield_energy_of_stretch` that gives ``psi_p`` (for the run log)."""
    return math.sqrt(2.0 * psi_p) * delta / (scale * (2.0 * mu + lam))


def time_step_micromodulus(dim: int, spacing: float, delta: float, influence: str,
                           partial_volumes: bool, scale: float, lam: float, mu: float) -> float:
    """c for the Silling-Askari rule sum_q V_q c w/|X| (moduli.py): a bond's axial stiffness
    is 2 beta (2 mu + lambda) w V_p V_q/|X|^2 (a PMB bond's: c w V_p V_q/|X|), so the c that
    gives the same sum over a full family."""
    args = (dim, spacing, delta, influence, partial_volumes)
    return 2.0 * scale * (2.0 * mu + lam) * full_family_sum(*args, power=-2) / \
        full_family_sum(*args, power=-1)


@njit(cache=True, error_model="numpy")
def _apply(F, p, X0, X1, X2, dim):
    """F_p X (third component 0 in 2D)."""
    if dim == 2:
        return F[p, 0, 0] * X0 + F[p, 0, 1] * X1, F[p, 1, 0] * X0 + F[p, 1, 1] * X1, 0.0
    return (F[p, 0, 0] * X0 + F[p, 0, 1] * X1 + F[p, 0, 2] * X2,
            F[p, 1, 0] * X0 + F[p, 1, 1] * X1 + F[p, 1, 2] * X2,
            F[p, 2, 0] * X0 + F[p, 2, 1] * X1 + F[p, 2, 2] * X2)


@njit(cache=True, error_model="numpy")
def bond_iso_stretches(x, x0, vol, offsets, slot, status, weight, n_owned, faces, clamp, out,
                       image):
    """out_p = sum_q w |X| (|Y| - |X|) V_q / sum_q w |X|^2 V_q over intact bonds: the LPS
    dilatation over d, the mean bond stretch (= J^{1/d} - 1 for an isotropic stretch, tr eps/d
    to first order for any uniform strain). With clamping ``faces`` the sums take p's ghost
    bonds too, and image[p, f] is the mean bond stretch of p's image across face f (the
    ghost's, which the ghost bonds of p's partners need; 0 out of reach): clamp.py,
    `clamp.ghost_stretch_sums`."""
    dim = x.shape[1]
    ghosts = ghost_scratch(offsets, faces)
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        num = 0.0
        den = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            xl = norm3(X0, X1, X2)
            wv = weight[b] * vol[q] * xl
            num += wv * (norm3(y0, y1, y2) - xl)
            den += wv * xl
        near = faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp)
        for fc in range(faces.shape[0]):
            image[p, fc] = 0.0
            if not near:
                continue
            num, den, image[p, fc], ng = ghost_stretch_sums(
                x, x0, vol, offsets, slot, status, weight, p, int(faces[fc, 0]), faces[fc, 1],
                clamp, ghosts, X, Y, num, den)
        for fc in range(faces.shape[0]):
            image[p, fc] = image[p, fc] / den if den > 0.0 else 0.0
        out[p] = num / den if den > 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def plastic_return(E_dev, k, xl, psi_p):
    """de_p of the corrected eq. 5.11 (0 inside the yield surface); k = w beta (2 mu + lam)."""
    if 0.5 * E_dev * E_dev - psi_p <= 0.0:
        return 0.0
    r = math.sqrt(2.0 * psi_p)
    return xl * (E_dev - (r if E_dev > 0.0 else -r)) / k


@njit(cache=True, error_model="numpy", inline="always")
def _lengths(y0, y1, y2, X0, X1, X2):
    """(|Y|, |X|, 1/|X|, s = |Y|/|X| - 1) of a bond: the bond loops divide by |X| once
    (their divisions and square roots bound their speed, as in pmb.py); the same numbers at
    both ends of a bond."""
    yl = norm3(y0, y1, y2)
    xl = norm3(X0, X1, X2)
    inv_xl = 1.0 / xl
    return yl, xl, inv_xl, yl * inv_xl - 1.0


@njit(cache=True, error_model="numpy")
def _bar_term(Fb0, Fb1, Fb2, inv_xl, ep, act, plastic, s):
    """(|Ybar|/|X| - 1 - e_p) dir(Ybar) (eq. 5.6), or (s - e_p) dir(Ybar) (eq. 5.9, plastic),
    times the point's active flag; ``inv_xl`` = 1/|X| (`_lengths`)."""
    if act == 0.0:
        return 0.0, 0.0, 0.0
    n = norm3(Fb0, Fb1, Fb2)
    c = ((s if plastic else n * inv_xl - 1.0) - ep) / n
    return c * Fb0, c * Fb1, c * Fb2


@njit(cache=True, error_model="numpy")
def bond_energy_forces(x, x0, vol, offsets, slot, status, weight, F, active, eiso, e_p,
                       beta, lam, mu, psi_p, commit, n_owned, f):
    """Return map of each intact bond (psi_p finite), then f_p = sum_q (T_p<X> - T_q<-X>)
    V_p V_q (module docstring) with the returned e_p. ``commit`` only decides whether the new
    e_p is stored (False: a trial force, the state untouched). F, active, eiso of owned + halo
    points."""
    dim = x.shape[1]
    stiff = 2.0 * mu + lam
    plastic = psi_p < np.inf
    for p in range(n_owned):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            yl, xl, inv_xl, s = _lengths(y0, y1, y2, X0, X1, X2)
            wb = beta * weight[b]
            ep = e_p[b] if plastic else 0.0     # an elastic body keeps no plastic stretch
            if plastic:
                e_dev = s - 0.5 * (eiso[p] + eiso[q])
                dep = plastic_return(wb * stiff * (e_dev - ep) * inv_xl, wb * stiff, xl, psi_p)
                # Dissipation: a return that would lengthen the elastic stretch s - e_p (and
                # so store energy in the bond) is not taken (module docstring).
                if abs(s - ep - dep) <= abs(s - ep):
                    ep += dep
                if commit:
                    e_p[b] = ep
            pb0, pb1, pb2 = _apply(F, p, X0, X1, X2, dim)
            qb0, qb1, qb2 = _apply(F, q, X0, X1, X2, dim)
            u0, u1, u2 = _bar_term(pb0, pb1, pb2, inv_xl, ep, active[p], plastic, s)
            v0, v1, v2 = _bar_term(qb0, qb1, qb2, inv_xl, ep, active[q], plastic, s)
            c_mu = 2.0 * mu * wb * inv_xl * (vol[p] * vol[q])
            c_lam = 2.0 * lam * wb * inv_xl * (s - ep) / yl * (vol[p] * vol[q])
            f0 += c_mu * (u0 + v0) + c_lam * y0
            f1 += c_mu * (u1 + v1) + c_lam * y1
            f2 += c_mu * (u2 + v2) + c_lam * y2
        f[p, 0] = f0
        f[p, 1] = f1
        if dim == 3:
            f[p, 2] = f2


@njit(cache=True, error_model="numpy")
def bond_energy_density(x, x0, vol, offsets, slot, status, weight, F, active, e_p, beta, lam,
                        mu, plastic, n_owned, out):
    """W_p = sum_q psi V_q over intact bonds (eq. 5.5 with beta; plastic: eq. 5.8's form)."""
    dim = x.shape[1]
    for p in range(n_owned):
        s_w = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            _, _, inv_xl, s = _lengths(y0, y1, y2, X0, X1, X2)
            sb = 0.0
            if plastic:
                s -= e_p[b]
                sb = s
            elif active[p] != 0.0:
                pb0, pb1, pb2 = _apply(F, p, X0, X1, X2, dim)
                sb = norm3(pb0, pb1, pb2) * inv_xl - 1.0
            s_w += beta * weight[b] * (mu * sb * sb + 0.5 * lam * s * s) * vol[q]
        out[p] = s_w


@njit(cache=True, error_model="numpy")
def _ghost_apply(F, q, X, axis, dim):
    """F_q' X for the ghost q' of q (clamp.py): F_q' = I - (F_q - I) R, R flipping the axis
    component, as the correspondence clamp takes it."""
    r0 = -X[0] if axis == 0 else X[0]
    r1 = -X[1] if axis == 1 else X[1]
    r2 = -X[2] if axis == 2 else X[2]
    a0, a1, a2 = _apply(F, q, r0, r1, r2, dim)
    return X[0] - (a0 - r0), X[1] - (a1 - r1), (X[2] - (a2 - r2)) if dim == 3 else 0.0


@njit(cache=True, error_model="numpy")
def bond_energy_clamp_terms(x, x0, vol, offsets, slot, status, F, active, eiso, eiso_image,
                            mirror_ep, shift, beta, lam, mu, psi_p, commit, n_owned, faces,
                            clamp, energy, f):
    """The clamp's ghost bonds (clamp.py) of the owned points within reach of a face, added
    to f (n_owned, d) as `bond_energy_forces` adds the real ones, or with ``energy`` their
    psi V_q to f[:, 0] (`bond_energy_density`). The ghost q' of q has the state of its source
    (F_q' = I - (F_q - I) R, active_q) and the mean bond stretch of q's image
    (eiso_image[q, f], `bond_iso_stretches`). A ghost bond has its own plastic stretch:
    mirror_ep[f][k + shift[p]] for p's ghost with source k (clamp.ghost_store; read and
    returned only with psi_p finite; ``commit`` as in `bond_energy_forces`)."""
    dim = x.shape[1]
    stiff = 2.0 * mu + lam
    plastic = psi_p < np.inf
    reach = clamp_reach(clamp)
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        if not near_a_face(x0, p, faces, clamp):
            continue
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for fc in range(faces.shape[0]):
            axis = int(faces[fc, 0])
            plane = faces[fc, 1]
            if abs(x0[p, axis] - plane) >= reach:
                continue
            for k in range(offsets[p] - 1, offsets[p + 1]):
                q, w = ghost_at(x, x0, offsets, slot, status, p, k, axis, plane, clamp, Y, X)
                if w == 0.0:
                    continue
                yl, xl, inv_xl, s = _lengths(Y[0], Y[1], Y[2], X[0], X[1], X[2])
                wb = beta * w
                ep = 0.0
                if plastic:
                    ep = mirror_ep[fc][k + shift[p]]
                if plastic and not energy:
                    e_dev = s - 0.5 * (eiso[p] + eiso_image[q, fc])
                    dep = plastic_return(wb * stiff * (e_dev - ep) * inv_xl, wb * stiff, xl,
                                         psi_p)
                    if abs(s - ep - dep) <= abs(s - ep):     # dissipation (module docstring)
                        ep += dep
                    if commit:
                        mirror_ep[fc][k + shift[p]] = ep
                pb0, pb1, pb2 = _apply(F, p, X[0], X[1], X[2], dim)
                if energy:
                    sb = s - ep
                    if not plastic:
                        sb = norm3(pb0, pb1, pb2) * inv_xl - 1.0 - ep if active[p] != 0.0 else 0.0
                    f0 += wb * (mu * sb * sb + 0.5 * lam * (s - ep) * (s - ep)) * vol[q]
                    continue
                qb0, qb1, qb2 = _ghost_apply(F, q, X, axis, dim)
                u0, u1, u2 = _bar_term(pb0, pb1, pb2, inv_xl, ep, active[p], plastic, s)
                v0, v1, v2 = _bar_term(qb0, qb1, qb2, inv_xl, ep, active[q], plastic, s)
                c_mu = 2.0 * mu * wb * inv_xl * (vol[p] * vol[q])
                c_lam = 2.0 * lam * wb * inv_xl * (s - ep) / yl * (vol[p] * vol[q])
                f0 += c_mu * (u0 + v0) + c_lam * Y[0]
                f1 += c_mu * (u1 + v1) + c_lam * Y[1]
                f2 += c_mu * (u2 + v2) + c_lam * Y[2]
        f[p, 0] += f0
        if not energy:
            f[p, 1] += f1
            if dim == 3:
                f[p, 2] += f2


@njit(cache=True, error_model="numpy")
def yield_values(x, x0, offsets, slot, status, weight, eiso, e_p, beta, lam, mu, psi_p,
                 n_owned, out):
    """f = E_dev^2/2 - psi_p of every half-bond (eq. 5.10; -inf for broken ones)."""
    dim = x.shape[1]
    stiff = 2.0 * mu + lam
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                out[b] = -np.inf
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            _, _, inv_xl, s = _lengths(y0, y1, y2, X0, X1, X2)
            e_dev = s - 0.5 * (eiso[p] + eiso[q])
            E = beta * weight[b] * stiff * (e_dev - e_p[b]) * inv_xl
            out[b] = 0.5 * E * E - psi_p


class BondEnergy:
    """Bond-energy model over a points view (integrator.PDPoints).

    Parameters
    ----------
    dim : 2 or 3.
    lam, mu : Lame constants (2D: of the plane-strain solid).
    scale : beta (`bond_energy_scale`).
    plastic_yield : psi_p (inf: elastic).
    critical_stretch : s0 (inf: no failure).
    time_step_c : micromodulus for the Silling-Askari step.
    """

    name = "bond_energy"

    def __init__(self, dim: int, lam: float, mu: float, scale: float,
                 plastic_yield: float = math.inf, critical_stretch: float = math.inf,
                 time_step_c: float = 0.0, clamp_faces=NO_FACES, clamp=NO_CLAMP):
        self.dim = dim
        self.lam = float(lam)
        self.mu = float(mu)
        self.beta = float(scale)
        self.psi_p = float(plastic_yield)
        self.s0 = float(critical_stretch)
        self.c_dt = float(time_step_c)
        self.clamp_faces = np.ascontiguousarray(clamp_faces, dtype=np.float64)
        self.clamp = np.ascontiguousarray(clamp, dtype=np.float64)
        nf = len(self.clamp_faces)
        self.halo_fields = ("F", "active", "eiso") + (("eiso_image",) if nf else ())
        # The ghost bonds' plastic stretches (bond_energy_clamp_terms), per face, in the
        # clamp's ghost store: only for the particles within reach of a clamped wall.
        self.ghost_states = mirror_state_names(nf) if self.psi_p < math.inf else ()
        self.persistent_fields = ()
        self.F = None
        self.resize(0)          # a rank may hold none of the body's particles

    def time_step_micromodulus(self) -> float:
        return self.c_dt

    def _declare_state(self, bonds) -> None:
        if self.psi_p < math.inf:       # an elastic body keeps no plastic stretch
            bonds.add_state(PLASTIC_STATE)

    def _plastic_stretch(self, bonds) -> np.ndarray:
        """The per-bond plastic stretch, zeros for an elastic body (which stores none)."""
        e_p = bonds.state.get(PLASTIC_STATE)
        return np.zeros(bonds.n_bonds) if e_p is None else e_p

    def setup(self, pts) -> None:
        self._declare_state(pts.bonds)
        attach_ghost_store(pts, self.clamp_faces, self.clamp, self.ghost_states)
        self.resize(len(pts.x))

    def resize(self, n: int) -> None:
        if self.F is not None and len(self.F) == n:
            return
        d = self.dim
        self.F = np.zeros((n, d, d))
        self.F[:] = np.eye(d)
        self.Kinv = np.zeros((n, d, d))
        self.active = np.zeros(n)
        self.eiso = np.zeros(n)
        self.eiso_image = np.zeros((n, len(self.clamp_faces)))

    def update_state(self, pts) -> int:
        b = pts.bonds
        self._declare_state(b)
        broken = correspondence_kinematics(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                           b.weight, self.s0, pts.n_owned, self.F, self.Kinv,
                                           self.active, self.clamp_faces, self.clamp)
        bond_iso_stretches(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                           pts.n_owned, self.clamp_faces, self.clamp, self.eiso,
                           self.eiso_image)
        return broken

    def _clamp_terms(self, pts, commit, energy, out) -> None:
        if not len(self.clamp_faces):
            return
        b = pts.bonds
        mirror, shift = ghost_arrays(pts, self.ghost_states)    # elastic: none, never read
        bond_energy_clamp_terms(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, self.F,
                                self.active, self.eiso, self.eiso_image, mirror, shift,
                                self.beta, self.lam, self.mu, self.psi_p, commit,
                                pts.n_owned, self.clamp_faces, self.clamp, energy, out)

    def forces(self, pts, f, commit: bool = True) -> int:
        b = pts.bonds
        bond_energy_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                           self.F, self.active, self.eiso, b.state.get(PLASTIC_STATE, NO_STATE),
                           self.beta, self.lam, self.mu, self.psi_p, commit, pts.n_owned, f)
        self._clamp_terms(pts, commit, False, f)
        return 0

    def energy_density(self, pts, out=None) -> np.ndarray:
        b = pts.bonds
        out = np.empty(pts.n_owned) if out is None else out
        bond_energy_density(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                            self.F, self.active, b.state.get(PLASTIC_STATE, NO_STATE), self.beta,
                            self.lam, self.mu, self.psi_p < math.inf, pts.n_owned, out)
        self._clamp_terms(pts, False, True, out.reshape(-1, 1))
        return out

    def yield_values(self, pts) -> np.ndarray:
        b = pts.bonds
        out = np.empty(b.n_bonds)
        yield_values(pts.x, pts.x0, b.offsets, b.slot, b.status, b.weight, self.eiso,
                     self._plastic_stretch(b), self.beta, self.lam, self.mu, self.psi_p,
                     pts.n_owned, out)
        return out

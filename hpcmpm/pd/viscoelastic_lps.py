"""Viscoelastic linearized LPS (003 eq. 5.12-5.20; Silling 2010 linearization, Mitchell 2011
Maxwell relaxation): ``model = "viscoelastic_lps"``.

The LPS (lps.py) is linearized about the configuration at the start of each step (the
positions at the last force evaluation, Y_ref), which becomes the reference of that step's
increment (003 eq. 5.17: the weighted volume with |Y|, not |X|):

    m_p      = sum_q w |Y_ref|^2 V_q
    theta_p  = (d / m_p) sum_q w |Y_ref| de V_q,       de = |Y| - |Y_ref|
    dt_p     = (d kappa theta_p / m_p) |Y_ref| + (alpha_m / m_p) (de - theta_p |Y_ref| / d)
                 `---- isotropic part ----'     `-------- deviatoric part -----------'

with alpha_m = 15 mu (3D), 8 mu (2D), w = omega * (partial volume). This is M[x_p] . U (eq.
5.12) with the issue's modulus state (eq. 5.19-5.20 are garbled: a lambda where mu belongs,
9 lambda/S^2 - mu/S for the first factor):

    M<Y1, Y2> = ((d^2 kappa - alpha_m) / m^2) w1 w2 Y1 (x) Y2 + (alpha_m / m) w1 dir1 (x) dir1 Delta(Y2 - Y1)

(3D: (9 kappa - 15 mu)/m^2 and 15 mu/m), contracted with the bond displacement U = dY (eq.
5.12's U[x_p]) to first order: dir . dY = de + O(dY^2). `modulus_state` assembles M for
verification.

Per bond (state arrays of `Bonds`, so they migrate and checkpoint with the bonds) the scalar
pair force density is stored, split as Mitchell's VES model splits the extension state:

    ve_iso  += w (dt_p,iso + dt_q,iso)                        accumulated (elastic volume)
    ve_dev   = g ve_dev + w (dt_p,dev + dt_q,dev) * h(dt/tau)  Maxwell: g = exp(-dt/tau)
    ve_len   = |Y|                                             the next step's reference

with h(z) = (1 - exp(-z)) / z (1 when tau = inf), the exact Maxwell update for a deviatoric
extension growing at a constant rate over the step (so steady shear gives exactly
mu tau gamma_dot). The force on p is (ve_iso + ve_dev) V_p V_q Y/|Y|: the stored scalar acts
along the current bond. Both ends of a bond update the same stored values from bitwise equal
inputs (t_p + t_q is symmetric), so the pair forces cancel exactly and no reverse
communication is needed.

``memory = "none"`` is the literal reading of eq. 5.14, which drops T[x_p, t^{n-1}]: the force
is the last increment only, ve_iso = w (dt_p,iso + dt_q,iso), ve_dev = w (...), i.e. a
viscous fluid whose viscosity is proportional to the step (about mu dt, see
scripts/study_pd_models.py), kept for comparison with the thesis. It stores no force, so its
bonds and the clamp's ghost store keep only the lengths (`state_fields`,
`ghost_state_names`).

tau = inf reproduces the total-Lagrangian LPS up to O(eps^2) in the strain (the stored
increments use |Y_ref| where the LPS uses |X|). Failure: the total stretch
(|Y| - |X|)/|X| > s0 (003 eq. 4.8), tested in the first pass on both ends.

The clamp at sticky walls (clamp.py; integral-based bodies): m and theta of a particle within
reach of such a wall sum over its ghost bonds too, each ghost bond updates its own stored
forces, and its ghost end uses the m and theta of the source's image family (``m_image``,
``theta_image``, refreshed in the halo). Every length in those sums enters as the previous
step's, so the clamp keeps per clamping face a ghost bond's reference length, stored forces
and image length for each ghost (of each partner and of the particle itself), and the
previous length of each bond's image, in its ghost store (`ghost_state_names`,
clamp.ghost_store: only the particles within reach of a clamped wall carry it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clamp import (NO_CLAMP, NO_FACES, attach_ghost_store, ghost_arrays, ghost_at, ghost_bond,
                    image_length, near_a_face)
from .geometry import bond_vectors, norm3, stretched_past
from .lps import shear_coefficient

MEMORIES = ("maxwell", "none")
STATE_FIELDS = ("ve_len", "ve_iso", "ve_dev")
NO_PAIRS = np.empty((0, 2))
_NO_FORCES = np.empty(0)


def state_fields(memory: str) -> tuple[str, ...]:
    """The per-bond state a model with this ``memory`` keeps: ``"none"`` stores no force (the
    force is the step's increment alone), only the lengths the increments are taken from."""
    return STATE_FIELDS if memory == "maxwell" else STATE_FIELDS[:1]


@njit(cache=True, error_model="numpy")
def ve_initial_lengths(x0, offsets, slot, n_owned, ref_len):
    """ve_len = |X| for half-bonds that have none yet (set-up; bonds merged mid-run)."""
    dim = x0.shape[1]
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            q = slot[b]
            if ref_len[b] > 0.0 or q < 0:
                continue
            d2 = 0.0
            for a in range(dim):
                t = x0[q, a] - x0[p, a]
                d2 += t * t
            ref_len[b] = math.sqrt(d2)


@njit(cache=True, error_model="numpy")
def ve_dilatation(x, x0, vol, offsets, slot, status, weight, ref_len, s0, n_owned, m, theta,
                  faces, clamp, ghost, shift, m_image, theta_image):
    """Failure on the total stretch, then m_p = sum w |Y_ref|^2 V_q and the step's dilatation
    increment theta_p = (d/m_p) sum w |Y_ref| (|Y| - |Y_ref|) V_q. With clamping ``faces``
    the sums take p's ghost bonds too, and m_image, theta_image[p, f] are those of p's image
    across face f (`_ghost_sums`; ``ghost``, ``shift``: the clamp's ghost store, clamp.ghost_arrays).
    Returns half-bonds broken."""
    dim = x.shape[1]
    broken = 0
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        sm = 0.0
        st = 0.0
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
            yl = norm3(y0, y1, y2)
            if stretched_past(yl - xl, xl, s0):
                status[b] = 0
                broken += 1
                continue
            r = ref_len[b]
            wv = weight[b] * vol[q]
            sm += wv * r * r
            st += wv * r * (yl - r)
        near = faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp)
        for fc in range(faces.shape[0]):
            m_image[p, fc] = 0.0
            theta_image[p, fc] = 0.0
            if near:
                sm, st = _ghost_sums(x, x0, vol, offsets, slot, status, weight, p, fc, faces,
                                     clamp, ghost, shift, m_image, theta_image, X, Y, sm,
                                     st)
        m[p] = sm
        theta[p] = dim * st / sm if sm > 0.0 else 0.0
    return broken


# The clamp's state (clamp.py) in its ghost store (clamp.ghost_store: only for the particles
# within reach of a clamped wall), per clamping face: each ghost bond's reference length,
# stored isotropic and deviatoric forces and the previous length of its image (the ghost bond
# of the source to this particle's image); at a half-bond's entry also the previous length of
# the bond's own image (IMAGE_LEN; unused at the own image's entry). The kernels take them as
# one tuple, GHOST_PER_FACE arrays a face, and p's entry for ghost source k at k + shift[p].
GHOST_QUANTITIES = ("mirror_len", "mirror_iso", "mirror_dev", "image_mirror_len")
MIRROR_LEN, MIRROR_ISO, MIRROR_DEV, IMAGE_MIRROR_LEN, IMAGE_LEN = range(5)
GHOST_PER_FACE = len(GHOST_QUANTITIES) + 1


def ghost_state_names(n_faces: int, memory: str = "maxwell") -> tuple[str, ...]:
    """The clamp's ghost-store states, face by face in the kernels' order (GHOST_QUANTITIES,
    then the previous length of the bond's image); ``memory = "none"`` stores no forces."""
    kept = [q for q in (*GHOST_QUANTITIES, "image_len")
            if memory == "maxwell" or q not in ("mirror_iso", "mirror_dev")]
    return tuple(f"ve_{q}{f}" for f in range(n_faces) for q in kept)


@njit(cache=True, inline="always")
def _gget(ghost, fc, what, shift, p, k):
    """Quantity ``what`` of p's ghost with source k (k = offsets[p] - 1: p's own image)."""
    return ghost[fc * GHOST_PER_FACE + what][k + shift[p]]


@njit(cache=True, inline="always")
def _gset(ghost, fc, what, shift, p, k, value):
    """Store quantity ``what`` of p's ghost with source k (as `_gget` reads it)."""
    ghost[fc * GHOST_PER_FACE + what][k + shift[p]] = value


@njit(cache=True, error_model="numpy")
def _ghost_sums(x, x0, vol, offsets, slot, status, weight, p, fc, faces, clamp, ghost, shift,
                m_image, theta_image, X, Y, sm, st):
    """p's ghost bonds across face fc added to its sums (sm, st), and the sums of p's image
    p' (clamp.py): the images p'-r' of p's intact bonds (reference length |X|, current
    Y' = R X - (u_r - u_p)) and the images p'-r of its ghost bonds p-r' (the ghost bond of
    r to p', `clamp.ghost_bond` from r). Each enters with its previous length as the
    linearization's reference (module docstring), which is state. Returns (sm, st)."""
    dim = x.shape[1]
    axis = int(faces[fc, 0])
    plane = faces[fc, 1]
    im_m = 0.0
    im_t = 0.0
    any_ghost = False
    for k in range(offsets[p] - 1, offsets[p + 1]):
        q, w = ghost_at(x, x0, offsets, slot, status, p, k, axis, plane, clamp, Y, X)
        if w == 0.0:
            continue
        any_ghost = True
        r = _gget(ghost, fc, MIRROR_LEN, shift, p, k)
        wv = w * vol[q]
        sm += wv * r * r
        st += wv * r * (norm3(Y[0], Y[1], Y[2]) - r)
        ghost_bond(x, x0, q, p, axis, plane, dim, Y, X)
        r = _gget(ghost, fc, IMAGE_MIRROR_LEN, shift, p, k)
        im_m += wv * r * r
        im_t += wv * r * (norm3(Y[0], Y[1], Y[2]) - r)
    if not any_ghost:
        return sm, st
    img = ghost[fc * GHOST_PER_FACE + IMAGE_LEN]
    for b in range(offsets[p], offsets[p + 1]):
        q = slot[b]
        if status[b] == 0 or q < 0:
            continue
        r = img[b + shift[p]]
        wv = weight[b] * vol[q]
        im_m += wv * r * r
        im_t += wv * r * (image_length(x, x0, p, q, axis, dim) - r)
    m_image[p, fc] = im_m
    theta_image[p, fc] = dim * im_t / im_m if im_m > 0.0 else 0.0
    return sm, st


@njit(cache=True, error_model="numpy")
def ve_clamp_initial_lengths(x0, offsets, slot, status, n_owned, faces, clamp, ghost, shift):
    """The clamp's lengths that have none yet (set-up) start at their reference lengths:
    |X'| for a ghost bond and for its image, |X| for the image of a bond."""
    dim = x0.shape[1]
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        if not near_a_face(x0, p, faces, clamp):
            continue
        for fc in range(faces.shape[0]):
            axis = int(faces[fc, 0])
            for k in range(offsets[p] - 1, offsets[p + 1]):
                q, _ = ghost_at(x0, x0, offsets, slot, status, p, k, axis, faces[fc, 1],
                                clamp, Y, X)
                if q < 0:
                    continue
                xl = norm3(X[0], X[1], X[2])
                for what in (MIRROR_LEN, IMAGE_MIRROR_LEN):
                    if _gget(ghost, fc, what, shift, p, k) == 0.0:
                        _gset(ghost, fc, what, shift, p, k, xl)
                if k >= offsets[p] and _gget(ghost, fc, IMAGE_LEN, shift, p, k) == 0.0:
                    _gset(ghost, fc, IMAGE_LEN, shift, p, k,
                          image_length(x0, x0, p, q, axis, dim))


@njit(cache=True, error_model="numpy")
def _end_rates(theta, m, kappa, alpha_m, dim):
    """(ci, cd, ct) of one end: its (isotropic, deviatoric) scalar force increments (without
    w) are ((d kappa theta/m) r, (alpha_m/m)(de - theta r/d)) = (ci r, cd de - ct r), with
    ci = d kappa theta/m, cd = alpha_m/m, ct = cd theta/d; zero where m <= 0. Per point, so
    the bond loop divides once a bond (as lps.end_coefficients)."""
    if m <= 0.0:
        return 0.0, 0.0, 0.0
    cd = alpha_m / m
    return dim * kappa * theta / m, cd, cd * theta / dim


@njit(cache=True, error_model="numpy", inline="always")
def _summed_increments(ci_p, cd_p, ct_p, ci_q, cd_q, ct_q, de, r):
    """Both ends' (isotropic, deviatoric) increments summed, symmetric in p and q:
    ((ci_p + ci_q) r, (cd_p + cd_q) de - (ct_p + ct_q) r) (`_end_rates`)."""
    return (ci_p + ci_q) * r, (cd_p + cd_q) * de - (ct_p + ct_q) * r


@njit(cache=True, error_model="numpy")
def _end_rate_arrays(theta, m, kappa, alpha_m, dim):
    """`_end_rates` of every point (owned + halo rows): arrays (n, 3)."""
    out = np.empty((theta.shape[0], 3))
    for p in range(theta.shape[0]):
        out[p, 0], out[p, 1], out[p, 2] = _end_rates(theta[p], m[p], kappa, alpha_m, dim)
    return out


@njit(cache=True, error_model="numpy")
def ve_forces(x, x0, vol, offsets, slot, status, weight, ref_len, s_iso, s_dev, m, theta,
              kappa, mu, decay, gain, memory_none, commit, n_owned, f, faces, clamp, ghost,
              shift, m_image, theta_image, pairs):
    """Per-bond stored forces updated with this step's increments (module docstring), then
    f_p = sum_q (ve_iso + ve_dev) V_p V_q Y/|Y|. ``decay`` = exp(-dt/tau), ``gain`` =
    (1 - decay)/(dt/tau); ``commit`` False leaves the state untouched (verification). With
    ``memory_none`` s_iso and s_dev are not read or written (they may be empty). ``pairs``
    (n_bonds x 2, or empty) receives each bond's (ve_iso, ve_dev) of the step
    (verification). With clamping ``faces``, p's ghost bonds too (`_ghost_forces`)."""
    dim = x.shape[1]
    alpha_m = shear_coefficient(mu, dim)
    c = _end_rate_arrays(theta, m, kappa, alpha_m, dim)
    acc = np.empty(3)
    X = np.empty(3)
    Y = np.empty(3)
    for p in range(n_owned):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            yl = norm3(y0, y1, y2)
            r = ref_len[b]
            de = yl - r
            inc_i, inc_d = _summed_increments(c[p, 0], c[p, 1], c[p, 2], c[q, 0], c[q, 1],
                                              c[q, 2], de, r)
            w = weight[b]
            if memory_none:
                si = w * inc_i
                sd = w * inc_d
            else:
                si = s_iso[b] + w * inc_i
                sd = decay * s_dev[b] + gain * (w * inc_d)
            if commit:
                if not memory_none:
                    s_iso[b] = si
                    s_dev[b] = sd
                ref_len[b] = yl
            if pairs.shape[0] > 0:
                pairs[b, 0] = si
                pairs[b, 1] = sd
            a = (si + sd) * (vol[p] * vol[q]) / yl
            f0 += a * y0
            f1 += a * y1
            f2 += a * y2
        if faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp):
            acc[0] = f0
            acc[1] = f1
            acc[2] = f2
            for fc in range(faces.shape[0]):
                _ghost_forces(x, x0, vol, offsets, slot, status, p, fc, faces, clamp, ghost,
                              shift,
                              m, theta, m_image, theta_image, kappa, alpha_m, decay, gain,
                              memory_none, commit, X, Y, acc)
            f0 = acc[0]
            f1 = acc[1]
            f2 = acc[2]
        f[p, 0] = f0
        f[p, 1] = f1
        if dim == 3:
            f[p, 2] = f2


@njit(cache=True, error_model="numpy")
def _ghost_forces(x, x0, vol, offsets, slot, status, p, fc, faces, clamp, ghost, shift, m,
                  theta, m_image, theta_image, kappa, alpha_m, decay, gain, memory_none, commit, X,
                  Y, acc):
    """The pair forces of p's ghost bonds across face fc, added to acc: each ghost bond
    updates its own stored forces as a real bond does, the ghost's end with the image's m
    and theta (m_image, theta_image of its source); on ``commit`` the lengths of the step
    become the next step's references (the ghost's, its image's and the images of p's
    bonds)."""
    dim = x.shape[1]
    axis = int(faces[fc, 0])
    plane = faces[fc, 1]
    for k in range(offsets[p] - 1, offsets[p + 1]):
        q, w = ghost_at(x, x0, offsets, slot, status, p, k, axis, plane, clamp, Y, X)
        if w == 0.0:
            continue
        yl = norm3(Y[0], Y[1], Y[2])
        r = _gget(ghost, fc, MIRROR_LEN, shift, p, k)
        de = yl - r
        ci_p, cd_p, ct_p = _end_rates(theta[p], m[p], kappa, alpha_m, dim)
        ci_q, cd_q, ct_q = _end_rates(theta_image[q, fc], m_image[q, fc], kappa, alpha_m, dim)
        inc_i, inc_d = _summed_increments(ci_p, cd_p, ct_p, ci_q, cd_q, ct_q, de, r)
        if memory_none:
            si = w * inc_i
            sd = w * inc_d
        else:
            si = _gget(ghost, fc, MIRROR_ISO, shift, p, k) + w * inc_i
            sd = decay * _gget(ghost, fc, MIRROR_DEV, shift, p, k) + gain * (w * inc_d)
        a = (si + sd) * (vol[p] * vol[q]) / yl
        for i in range(dim):
            acc[i] += a * Y[i]
        if commit:
            if not memory_none:
                _gset(ghost, fc, MIRROR_ISO, shift, p, k, si)
                _gset(ghost, fc, MIRROR_DEV, shift, p, k, sd)
            _gset(ghost, fc, MIRROR_LEN, shift, p, k, yl)
            ghost_bond(x, x0, q, p, axis, plane, dim, Y, X)
            _gset(ghost, fc, IMAGE_MIRROR_LEN, shift, p, k, norm3(Y[0], Y[1], Y[2]))
    if commit:
        img = ghost[fc * GHOST_PER_FACE + IMAGE_LEN]
        for b in range(offsets[p], offsets[p + 1]):
            q = slot[b]
            if status[b] != 0 and q >= 0:
                img[b + shift[p]] = image_length(x, x0, p, q, axis, dim)


def modulus_state(x, vol, bonds, p: int, kappa: float, mu: float) -> np.ndarray:
    """The issue's modulus state of point p about the current configuration (taken as the
    reference: m with |Y|, eq. 5.17), as blocks M[i, j] (k, k, d, d) over p's intact bonds
    i, j in segment order: dT_p<Y_i> = sum_j M[i, j] dY_j V_j (verification; plain numpy)."""
    dim = x.shape[1]
    alpha_m = shear_coefficient(mu, dim)
    sl = slice(bonds.offsets[p], bonds.offsets[p + 1])
    keep = bonds.status[sl] != 0
    q = bonds.slot[sl][keep]
    w = bonds.weight[sl][keep]
    Y = x[q] - x[p]
    yl = np.linalg.norm(Y, axis=1)
    m = np.sum(w * yl * yl * vol[q])
    wy = w[:, None] * Y
    M = ((dim * dim * kappa - alpha_m) / m ** 2) * np.einsum("ia,jb->ijab", wy, wy)
    dirs = Y / yl[:, None]
    k = len(q)
    # Delta(Y2 - Y1) with the quadrature volume V_j: the diagonal block divided by V_i.
    M[np.arange(k), np.arange(k)] += (alpha_m / m) * (w / vol[q])[:, None, None] * \
        np.einsum("ia,ib->iab", dirs, dirs)
    return M


class ViscoelasticLPS:
    """Viscoelastic LPS over a points view (integrator.PDPoints); per-bond state in
    ``bonds.state`` (`state_fields`), per-point m and theta recomputed each step and refreshed
    in the halo.

    Parameters
    ----------
    bulk : K (3D) or kappa (2D).
    mu : shear modulus.
    relaxation_time : tau of the deviatoric part (inf: elastic, the linearized LPS).
    memory : "maxwell" (stored forces) or "none" (eq. 5.14 literally).
    critical_stretch : s0 (inf: no failure).
    time_step_c : micromodulus of the PMB solid with the same P-wave modulus.
    """

    name = "viscoelastic_lps"

    def __init__(self, bulk: float, mu: float, relaxation_time: float = math.inf,
                 memory: str = "maxwell", critical_stretch: float = math.inf,
                 time_step_c: float = 0.0, clamp_faces=NO_FACES, clamp=NO_CLAMP):
        if memory not in MEMORIES:
            raise ValueError(f"memory must be one of {', '.join(MEMORIES)}, got {memory!r}")
        self.kappa = float(bulk)
        self.mu = float(mu)
        self.tau = float(relaxation_time)
        self.memory = memory
        self.s0 = float(critical_stretch)
        self.c_dt = float(time_step_c)
        self.dt = math.nan          # the step being integrated (set by the driver)
        self.clamp_faces = np.ascontiguousarray(clamp_faces, dtype=np.float64)
        self.clamp = np.ascontiguousarray(clamp, dtype=np.float64)
        nf = len(self.clamp_faces)
        self.halo_fields = ("m", "theta") + (("m_image", "theta_image") if nf else ())
        # The clamp's history, in its ghost store (only near a clamped wall).
        self.ghost_states = ghost_state_names(nf, memory)
        self.persistent_fields = ()
        self.m = np.empty(0)
        self.theta = np.empty(0)
        self.m_image = np.empty((0, nf))
        self.theta_image = np.empty((0, nf))

    def time_step_micromodulus(self) -> float:
        return self.c_dt

    def relaxation(self, dt: float) -> tuple[float, float]:
        """(decay, gain) = (exp(-dt/tau), (1 - exp(-dt/tau)) / (dt/tau))."""
        if not math.isfinite(self.tau):
            return 1.0, 1.0
        z = dt / self.tau
        decay = math.exp(-z)
        return decay, (-math.expm1(-z) / z if z > 0.0 else 1.0)

    def _declare_state(self, bonds) -> None:
        for name in state_fields(self.memory):
            bonds.add_state(name)

    def _ghost(self, pts) -> tuple[tuple, np.ndarray]:
        """The ghost store's arrays in the kernels' layout (GHOST_PER_FACE a face) and the
        shift; ``memory = "none"`` stores no forces, so empty placeholders stand in their
        places (the kernels neither read nor write them then)."""
        ghost, shift = ghost_arrays(pts, self.ghost_states)
        if self.memory == "none" and len(self.clamp_faces):
            store = pts.ghosts.state
            ghost = tuple(store.get(name, _NO_FORCES)
                          for name in ghost_state_names(len(self.clamp_faces)))
        return ghost, shift

    def setup(self, pts) -> None:
        self._declare_state(pts.bonds)
        attach_ghost_store(pts, self.clamp_faces, self.clamp, self.ghost_states)
        self.resize(len(pts.x))

    def resize(self, n: int) -> None:
        if len(self.m) != n:
            self.m = np.zeros(n)
            self.theta = np.zeros(n)
            self.m_image = np.zeros((n, len(self.clamp_faces)))
            self.theta_image = np.zeros((n, len(self.clamp_faces)))

    def update_state(self, pts) -> int:
        b = pts.bonds
        self._declare_state(b)          # bonds restored or arrived without the state
        ve_initial_lengths(pts.x0, b.offsets, b.slot, pts.n_owned, b.state["ve_len"])
        ghost, shift = self._ghost(pts)
        if len(self.clamp_faces):
            ve_clamp_initial_lengths(pts.x0, b.offsets, b.slot, b.status, pts.n_owned,
                                     self.clamp_faces, self.clamp, ghost, shift)
        return ve_dilatation(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                             b.state["ve_len"], self.s0, pts.n_owned, self.m, self.theta,
                             self.clamp_faces, self.clamp, ghost, shift, self.m_image,
                             self.theta_image)

    def forces(self, pts, f, commit: bool = True, pairs=NO_PAIRS) -> int:
        """The step's forces into f (`ve_forces`); ``pairs`` (n_bonds x 2) receives each
        bond's stored isotropic and deviatoric force of the step (verification)."""
        if self.memory == "maxwell" and math.isfinite(self.tau) and not self.dt > 0.0:
            raise RuntimeError("viscoelastic_lps: the driver must set model.dt before forces")
        decay, gain = self.relaxation(self.dt) if self.memory == "maxwell" else (1.0, 1.0)
        b = pts.bonds
        ghost, shift = self._ghost(pts)
        s_iso = b.state.get("ve_iso", _NO_FORCES)
        s_dev = b.state.get("ve_dev", _NO_FORCES)
        ve_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                  b.state["ve_len"], s_iso, s_dev, self.m, self.theta, self.kappa, self.mu,
                  decay, gain, self.memory == "none", commit, pts.n_owned, f,
                  self.clamp_faces, self.clamp, ghost, shift, self.m_image,
                  self.theta_image, pairs)
        return 0

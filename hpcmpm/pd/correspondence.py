"""Non-ordinary state-based (correspondence) peridynamics: any continuum stress through F.

003 eq. 4.4-4.7 with the issue's corrections. With w = omega beta (families.py), over intact
bonds:

    K_p = sum_q w X (x) X V_q                       (eq. 4.5, shape tensor)
    F_p = (sum_q w Y (x) X V_q) K_p^-1              (eq. 4.4)
    T_p<X> = w P_p K_p^-1 X,  P = J sigma F^-T = tau F^-T
                                   (eq. 4.7 prints det F F^-1 sigma, which is P^T)
    strain for output: eps = sym(F) - I             (eq. 4.6 as printed is not symmetric)

and the force on p (003 eq. 4.1 times V_p): f_p = sum_q (T_p<X> - T_q<-X>) V_p V_q
= sum_q w (A_p + A_q) X V_p V_q with A = P K^-1, plus Silling's (2017, J. Elasticity 127)
zero-energy-mode control: a penalty on the non-affine part z = Y - F X of each bond,
T^s_p<X> = G w z_p / |X| with G = `stabilization` * c (c: the PMB micromodulus of the same bulk
modulus, so G = c is a PMB bond's stiffness), giving f_p += sum_q (G w/|X|)(z_p + z_q') V_p V_q
with z_q' = Y - F_q X.

Callback-free: `correspondence_kinematics` (failure, K, F) on owners -> the caller evaluates the
Kirchhoff stress tau(F) with any material kernel -> `correspondence_force_state` (A = tau
F^-T K^-1) on owners -> the caller refreshes A, F, ``active`` in the halo ->
`correspondence_forces`. An attached particle with det F <= 0 gets A = NaN (the engine's health
check reports it). A particle whose K is ill-conditioned (fewer than d independent
intact bonds: det K < 1e-6 (tr K / d)^d) is detached: F = I, A = 0, active = 0; it carries no
PD stress and no stabilization, and is never reported as an inverted element by itself.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clamp import NO_CLAMP, NO_FACES, ghost_family, ghost_scratch, near_a_face
from .geometry import bond_vectors, norm3, stretched_past

# det K below this fraction of (tr K / d)^d: the family does not span the space.
DETACHED_RCOND = 1e-6


@njit(cache=True, error_model="numpy")
def _invert(M, out, dim):
    """out = M^-1 for dim 2 or 3; returns det M."""
    if dim == 2:
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        inv = 1.0 / det
        out[0, 0] = M[1, 1] * inv
        out[0, 1] = -M[0, 1] * inv
        out[1, 0] = -M[1, 0] * inv
        out[1, 1] = M[0, 0] * inv
        return det
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    inv = 1.0 / det
    out[0, 0] = c00 * inv
    out[1, 0] = c01 * inv
    out[2, 0] = c02 * inv
    out[0, 1] = (M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]) * inv
    out[1, 1] = (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]) * inv
    out[2, 1] = (M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]) * inv
    out[0, 2] = (M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]) * inv
    out[1, 2] = (M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]) * inv
    out[2, 2] = (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]) * inv
    return det


@njit(cache=True, error_model="numpy", inline="always")
def _add_outer(M, a0, a1, a2, X0, X1, X2, dim):
    """M += a (x) X (d x d), written out per d: no loop over a run-time d."""
    M[0, 0] += a0 * X0
    M[0, 1] += a0 * X1
    M[1, 0] += a1 * X0
    M[1, 1] += a1 * X1
    if dim == 3:
        M[0, 2] += a0 * X2
        M[1, 2] += a1 * X2
        M[2, 0] += a2 * X0
        M[2, 1] += a2 * X1
        M[2, 2] += a2 * X2


@njit(cache=True, error_model="numpy", inline="always")
def _add_bond(K, N, wv, X0, X1, X2, Y0, Y1, Y2, dim):
    """K += wv X (x) X and N += wv Y (x) X: one bond's term of the shape tensor and of the
    deformed-bond sum (F = N K^-1), shared by the intact and the clamp ghost bonds. Each term
    is (wv X_i) X_j, as the loops over i, j formed it (bitwise the same)."""
    _add_outer(K, wv * X0, wv * X1, wv * X2, X0, X1, X2, dim)
    _add_outer(N, wv * Y0, wv * Y1, wv * Y2, X0, X1, X2, dim)


@njit(cache=True, error_model="numpy")
def _ghost_bonds(x, x0, vol, offsets, slot, status, p, faces, clamp, dim, ghosts, K, N,
                 A, F, active, G, acc, forces):
    """p's ghost bonds (clamp.py): add them to its K and N, or with ``forces`` add their pair
    forces to acc (the ghost's state from its source: A_q' = A_q, F_q' = I - (F_q - I) R).
    ``ghosts``: `clamp.ghost_scratch`."""
    GX, GY, GW, GQ = ghosts
    for f in range(faces.shape[0]):
        axis = int(faces[f, 0])
        ng = ghost_family(x, x0, offsets, slot, status, p, axis, faces[f, 1], clamp, GX, GY,
                          GW, GQ)
        for g in range(ng):
            q = GQ[g]
            w = GW[g]
            if not forces:
                _add_bond(K, N, w * vol[q], GX[g, 0], GX[g, 1], GX[g, 2], GY[g, 0], GY[g, 1],
                          GY[g, 2], dim)
                continue
            vv = vol[p] * vol[q]
            gs = G * w / norm3(GX[g, 0], GX[g, 1], GX[g, 2])
            for i in range(dim):
                tp = 0.0
                tq = 0.0
                zp = GY[g, i]
                zq = GY[g, i] - GX[g, i]
                for j in range(dim):
                    tp += A[p, i, j] * GX[g, j]
                    tq += A[q, i, j] * GX[g, j]
                    zp -= F[p, i, j] * GX[g, j]
                    # (F_q - I) R X: R flips the axis component of X
                    zq += (F[q, i, j] - (1.0 if i == j else 0.0)) * \
                        (-GX[g, j] if j == axis else GX[g, j])
                acc[i] += (w * (tp + tq) + gs * (active[p] * zp + active[q] * zq)) * vv


@njit(cache=True, error_model="numpy")
def correspondence_kinematics(x, x0, vol, offsets, slot, status, weight, s0, n_owned,
                              F, Kinv, active, faces, clamp):
    """Failure (stretch > s0 breaks), then K^-1 and F of the owned points (F, Kinv
    (n, d, d), active (n,) 1.0/0.0). Returns the number of half-bonds broken. ``faces``
    (nf, 2): (axis, plane) of clamping walls and ``clamp`` (delta, spacing, linear influence)
    add the ghost bonds of clamp.py (nf = 0: none)."""
    dim = x.shape[1]
    K = np.empty((dim, dim))
    N = np.empty((dim, dim))
    Ki = np.empty((dim, dim))
    acc = np.empty(3)       # _ghost_bonds' force accumulator, unused here
    ghosts = ghost_scratch(offsets, faces)
    broken = 0
    for p in range(n_owned):
        K[:, :] = 0.0
        N[:, :] = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            q = slot[b]
            if q < 0:               # partner beyond the halo reach (pmb.py)
                status[b] = 0
                broken += 1
                continue
            Y0, Y1, Y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
            xl = norm3(X0, X1, X2)
            if stretched_past(norm3(Y0, Y1, Y2) - xl, xl, s0):
                status[b] = 0
                broken += 1
                continue
            _add_bond(K, N, weight[b] * vol[q], X0, X1, X2, Y0, Y1, Y2, dim)
        if faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp):
            _ghost_bonds(x, x0, vol, offsets, slot, status, p, faces, clamp, dim, ghosts, K, N,
                         F, F, active, 0.0, acc, False)     # A, acc unused
        tr = 0.0
        for i in range(dim):
            tr += K[i, i]
        det = _invert(K, Ki, dim)
        if not (tr > 0.0 and det > DETACHED_RCOND * (tr / dim) ** dim):
            active[p] = 0.0
            for i in range(dim):
                for j in range(dim):
                    F[p, i, j] = 1.0 if i == j else 0.0
                    Kinv[p, i, j] = 0.0
            continue
        active[p] = 1.0
        for i in range(dim):
            for j in range(dim):
                Kinv[p, i, j] = Ki[i, j]
                s = 0.0
                for k in range(dim):
                    s += N[i, k] * Ki[k, j]
                F[p, i, j] = s
    return broken


@njit(cache=True, error_model="numpy", inline="always")
def _spans(M, det, dim):
    """det M > 0 and M spans the space by the criterion of a detached family's K:
    det M > DETACHED_RCOND (|M|_F^2 / d)^(d/2) (a bond sum N whose bonds are deformed
    onto a line or a plane is as degenerate as a K whose bonds are)."""
    f2 = 0.0
    for i in range(dim):
        for j in range(dim):
            f2 += M[i, j] * M[i, j]
    return det > 0.0 and det > DETACHED_RCOND * (f2 / dim) ** (0.5 * dim)


@njit(cache=True, error_model="numpy")
def _deformation_sums(x, x0, vol, offsets, slot, status, weight, p, dim, faces, clamp,
                      ghosts, K, N, acc, unused, active):
    """K = N = 0, then N_p = sum_q w Y (x) X V_q over p's intact bonds at positions ``x``
    and its clamp ghost bonds (K collects the shape tensor alongside; acc (3,) scratch;
    ``unused`` (m, d, d) and ``active`` only type `_ghost_bonds`' force arguments, which it
    does not read here)."""
    K[:, :] = 0.0
    N[:, :] = 0.0
    for b in range(offsets[p], offsets[p + 1]):
        q = slot[b]
        if status[b] == 0 or q < 0:
            continue
        Y0, Y1, Y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
        _add_bond(K, N, weight[b] * vol[q], X0, X1, X2, Y0, Y1, Y2, dim)
    if faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp):
        _ghost_bonds(x, x0, vol, offsets, slot, status, p, faces, clamp, dim, ghosts, K, N,
                     unused, unused, active, 0.0, acc, False)


@njit(cache=True, error_model="numpy")
def correspondence_rate(x_new, x_old, x0, vol, offsets, slot, status, weight, active,
                        n_owned, dt, faces, clamp, L):
    """The velocity gradient of each owned point's PD family over a step from positions
    ``x_old`` to ``x_new`` (owned + halo): L_p = (F_p(x_new) F_p(x_old)^-1 - I) / dt, so that
    I + dt L_p is the family's exact deformation over the step (F = N K^-1 with the same
    intact bonds at both ends, ghost bonds included: K cancels, I + dt L = N_new N_old^-1).
    With x_new - x_old = dt v it is F_dot F^-1 for the velocities v that moved the points,
    the rate the correspondence force works on: sum_p f_p . v_p = -sum_p V_p P_p : F_dot_p
    (eq. 4.7 summed by parts). L = 0 where the family carries no PD stress (detached,
    ``active`` 0, or inverted, det F <= 0: its A is zeroed) or is degenerate at either end
    (`_spans`: bonds deformed onto a line give a singular increment)."""
    dim = x_new.shape[1]
    K = np.empty((dim, dim))
    N1 = np.empty((dim, dim))
    N0 = np.empty((dim, dim))
    N0i = np.empty((dim, dim))
    acc = np.empty(3)
    ghosts = ghost_scratch(offsets, faces)
    for p in range(n_owned):
        L[p, :, :] = 0.0
        if active[p] == 0.0:
            continue
        _deformation_sums(x_old, x0, vol, offsets, slot, status, weight, p, dim, faces, clamp,
                          ghosts, K, N0, acc, L, active)
        _deformation_sums(x_new, x0, vol, offsets, slot, status, weight, p, dim, faces, clamp,
                          ghosts, K, N1, acc, L, active)
        if not (_spans(N0, _invert(N0, N0i, dim), dim) and
                _spans(N1, _invert(N1, K, dim), dim)):
            continue
        for i in range(dim):
            for j in range(dim):
                s = 0.0
                for k in range(dim):
                    s += N1[i, k] * N0i[k, j]
                L[p, i, j] = (s - (1.0 if i == j else 0.0)) / dt


@njit(cache=True, error_model="numpy")
def correspondence_force_state(F, Kinv, tau, active, n_owned, A):
    """A_p = P_p K_p^-1 with P = tau F^-T (first Piola-Kirchhoff from the Kirchhoff stress);
    0 for detached points."""
    dim = F.shape[1]
    Fi = np.empty((dim, dim))
    P = np.empty((dim, dim))
    for p in range(n_owned):
        if active[p] == 0.0:
            A[p, :, :] = 0.0
            continue
        if not _invert(F[p], Fi, dim) > 0.0:
            # An inverted PD family: NaN reaches the engine's health check.
            A[p, :, :] = np.nan
            continue
        for i in range(dim):
            for j in range(dim):
                s = 0.0
                for k in range(dim):
                    s += tau[p, i, k] * Fi[j, k]     # (tau F^-T)_ij
                P[i, j] = s
        for i in range(dim):
            for j in range(dim):
                s = 0.0
                for k in range(dim):
                    s += P[i, k] * Kinv[p, k, j]
                A[p, i, j] = s


@njit(cache=True, error_model="numpy", inline="always")
def _pair_force_row_3d(A, F, p, q, i, y, X0, X1, X2, w, gs, ap, aq, vv):
    """Component i of the force on p from the bond p-q in 3D (module docstring), y = Y_i:
    the rows' sums written out in the order of a loop over j (0.0 + a_0 X_0 + ...,
    y - b_0 X_0 - ...), so bitwise those sums."""
    tp = 0.0 + A[p, i, 0] * X0 + A[p, i, 1] * X1 + A[p, i, 2] * X2
    tq = 0.0 + A[q, i, 0] * X0 + A[q, i, 1] * X1 + A[q, i, 2] * X2
    zp = y - F[p, i, 0] * X0 - F[p, i, 1] * X1 - F[p, i, 2] * X2
    zq = y - F[q, i, 0] * X0 - F[q, i, 1] * X1 - F[q, i, 2] * X2
    return (w * (tp + tq) + gs * (ap * zp + aq * zq)) * vv


@njit(cache=True, error_model="numpy", inline="always")
def _pair_force_row_2d(A, F, p, q, i, y, X0, X1, w, gs, ap, aq, vv):
    """`_pair_force_row_3d` in 2D (A and F are d x d: the 3D row would read past them). Two
    functions, not one branching on d in each row: that one ran at 6.0-6.4 ms a call where
    these run at 3.7-3.8 (spb_chocolate_drop_3d's bonds)."""
    tp = 0.0 + A[p, i, 0] * X0 + A[p, i, 1] * X1
    tq = 0.0 + A[q, i, 0] * X0 + A[q, i, 1] * X1
    zp = y - F[p, i, 0] * X0 - F[p, i, 1] * X1
    zq = y - F[q, i, 0] * X0 - F[q, i, 1] * X1
    return (w * (tp + tq) + gs * (ap * zp + aq * zq)) * vv


@njit(cache=True, error_model="numpy", inline="always")
def _pair_force(x, x0, vol, p, q, dim, w, A, F, active, G):
    """The force on p from the bond p-q (module docstring), as 3 scalars (the third 0 in
    2D); symmetric factors only. The rows are written out per d: at 2.6x the speed of
    loops over a run-time d with the bond vectors in scratch arrays, bitwise the same
    (measured on spb_chocolate_drop_3d's 215 000 bonds: 9.8 ms a call before, 3.7 after)."""
    Y0, Y1, Y2, X0, X1, X2 = bond_vectors(x, x0, p, q, dim)
    vv = vol[p] * vol[q]
    gs = G * w / norm3(X0, X1, X2)
    ap = active[p]
    aq = active[q]
    if dim == 3:
        return (_pair_force_row_3d(A, F, p, q, 0, Y0, X0, X1, X2, w, gs, ap, aq, vv),
                _pair_force_row_3d(A, F, p, q, 1, Y1, X0, X1, X2, w, gs, ap, aq, vv),
                _pair_force_row_3d(A, F, p, q, 2, Y2, X0, X1, X2, w, gs, ap, aq, vv))
    return (_pair_force_row_2d(A, F, p, q, 0, Y0, X0, X1, w, gs, ap, aq, vv),
            _pair_force_row_2d(A, F, p, q, 1, Y1, X0, X1, w, gs, ap, aq, vv), 0.0)


@njit(cache=True, error_model="numpy")
def correspondence_forces(x, x0, vol, offsets, slot, status, weight, A, F, active, G,
                          n_owned, f, faces, clamp):
    """f_p = sum_q [w (A_p + A_q) X + (G w/|X|)(z_p + z_q)] V_p V_q over intact bonds, then
    over the ghost bonds of ``faces``/``clamp`` (as `correspondence_kinematics`); A, F,
    active of owned + halo points."""
    dim = x.shape[1]
    acc = np.empty(3)
    unused = np.empty((dim, dim))      # _ghost_bonds' K, N
    ghosts = ghost_scratch(offsets, faces)
    for p in range(n_owned):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            f0, f1, f2 = _pair_force(x, x0, vol, p, slot[b], dim, weight[b], A, F, active, G)
            a0 += f0
            a1 += f1
            a2 += f2
        acc[0] = a0
        acc[1] = a1
        acc[2] = a2
        if faces.shape[0] > 0 and near_a_face(x0, p, faces, clamp):
            _ghost_bonds(x, x0, vol, offsets, slot, status, p, faces, clamp, dim, ghosts,
                         unused, unused, A, F, active, G, acc, True)
        for i in range(dim):
            f[p, i] = acc[i]


@njit(cache=True, error_model="numpy")
def stabilization_energy(x, x0, vol, offsets, slot, status, weight, F, active, G, n_owned):
    """sum_p a_p V_p sum_q (G w / (2|X|)) |Y - F_p X|^2 V_q: the zero-energy-mode
    penalty's energy, for the energy diagnostics. Not exactly the potential of the control
    force in `correspondence_forces`: that force is this energy's gradient at fixed F_p,
    but F_p is the least-squares fit with the weights w while the penalty weighs w/|X|, so
    F_p's own variation contributes too (measured on the perturbed 12^2 and 7^3 lattices of
    tests/unit/test_spb_pd_rate.py, G = 1.3: the energy's directional derivative and the
    control's work differ by 1.5 % in 2D and 2.5 % in 3D)."""
    dim = x.shape[1]
    Xv = np.empty(3)
    Yv = np.empty(3)
    total = 0.0
    for p in range(n_owned):
        if active[p] == 0.0:
            continue
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            Yv[0], Yv[1], Yv[2], Xv[0], Xv[1], Xv[2] = bond_vectors(x, x0, p, slot[b], dim)
            z2 = 0.0
            for i in range(dim):
                z = Yv[i]
                for j in range(dim):
                    z -= F[p, i, j] * Xv[j]
                z2 += z * z
            s += weight[b] * z2 / norm3(Xv[0], Xv[1], Xv[2]) * vol[slot[b]]
        total += 0.5 * G * s * vol[p]
    return total


@njit(cache=True, error_model="numpy")
def correspondence_bond_forces(x, x0, vol, offsets, slot, status, weight, A, F, active, G,
                               n_owned, out):
    """The per-half-bond terms of `correspondence_forces`, out (nb, d) (verification)."""
    dim = x.shape[1]
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            out[b, :] = 0.0
            if status[b] == 0:
                continue
            f0, f1, f2 = _pair_force(x, x0, vol, p, slot[b], dim, weight[b], A, F, active, G)
            out[b, 0] = f0
            out[b, 1] = f1
            if dim == 3:
                out[b, 2] = f2


class Correspondence:
    """Correspondence model over a points view (integrator.PDPoints).

    Parameters
    ----------
    dim : 2 or 3.
    stress : callable(F (n, d, d), tau (n, d, d)) writing the Kirchhoff stress of a material
        (e.g. a hpcmpm material's stress kernel with its moduli bound); the engine instead
        calls `kinematics`, evaluates its material, then `set_stress`.
    energy : callable(F (n, d, d), vol (n,)) -> sum_p vol_p psi(F_p) of the same material
        (for `strain_energy`; None: the stress material's energy is not counted).
    stabilization_modulus : G = stabilization * c.
    critical_stretch : s0 (inf: no failure).
    time_step_c : micromodulus of the PMB solid with the same P-wave modulus.
    clamp_faces, clamp : the sticky walls, (axis, plane) rows, and the `clamp.clamp_parameters`
        of the ghost bonds that clamp the body there (clamp.py; default: no clamp).
    """

    name = "correspondence"
    persistent_fields: tuple[str, ...] = ()
    halo_fields = ("A", "F", "active")

    def __init__(self, dim: int, stress=None, stabilization_modulus: float = 0.0,
                 critical_stretch: float = math.inf, time_step_c: float = 0.0, energy=None,
                 clamp_faces=NO_FACES, clamp=NO_CLAMP):
        self.dim = dim
        self.clamp_faces = np.ascontiguousarray(clamp_faces, dtype=np.float64)
        self.clamp = np.ascontiguousarray(clamp, dtype=np.float64)
        self.stress = stress
        self.energy = energy
        self.G = float(stabilization_modulus)
        self.s0 = float(critical_stretch)
        self.c_dt = float(time_step_c)
        self.F = np.empty((0, dim, dim))

    def time_step_micromodulus(self) -> float:
        return self.c_dt

    def setup(self, pts) -> None:
        self.resize(len(pts.x))

    def resize(self, n: int) -> None:
        """Scratch for n owned + halo points."""
        if len(self.F) == n:
            return
        d = self.dim
        self.F = np.zeros((n, d, d))
        self.F[:] = np.eye(d)
        self.Kinv = np.zeros((n, d, d))
        self.A = np.zeros((n, d, d))
        self.active = np.zeros(n)
        self.tau = np.zeros((n, d, d))

    def kinematics(self, pts) -> int:
        b = pts.bonds
        return correspondence_kinematics(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                         b.weight, self.s0, pts.n_owned, self.F, self.Kinv,
                                         self.active, self.clamp_faces, self.clamp)

    def set_stress(self, tau, n_owned: int) -> None:
        correspondence_force_state(self.F, self.Kinv, tau, self.active, n_owned, self.A)

    def update_state(self, pts) -> int:
        broken = self.kinematics(pts)
        n = pts.n_owned
        self.stress(self.F[:n], self.tau[:n])
        self.set_stress(self.tau, n)
        return broken

    def strain_energy(self, pts) -> float:
        """sum_p V_p (psi(F_p) + zero-energy-mode penalty) over the owned points at their
        current positions, F recomputed into scratch (the model's F, A of the last force pass
        are left alone; F with the clamp's ghost bonds, whose own penalty is not counted).
        Reads the intact bonds of ``pts`` as they are (the caller breaks the over-stretched
        ones on a copy first)."""
        b, n, d = pts.bonds, pts.n_owned, self.dim
        F, Kinv, active = np.empty((n, d, d)), np.empty((n, d, d)), np.empty(n)
        correspondence_kinematics(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                  b.weight, math.inf, n, F, Kinv, active, self.clamp_faces,
                                  self.clamp)
        total = stabilization_energy(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status,
                                     b.weight, F, active, self.G, n)
        if self.energy is not None:
            total += self.energy(F, np.ascontiguousarray(pts.vol[:n]))
        return float(total)

    def forces(self, pts, f) -> int:
        b = pts.bonds
        correspondence_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                              self.A, self.F, self.active, self.G, pts.n_owned, f,
                              self.clamp_faces, self.clamp)
        return 0

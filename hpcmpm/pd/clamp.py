"""A peridynamic clamp at sticky domain walls: the mirror images of a PD particle's family
across the wall (not in 003; issue 11's patch test needs it).

A sticky wall holds the grid nodes on it. A PD particle within a horizon of it has a family
cut by the wall, so its bonds pull it into the body and the wall holds it only through the
grid: a compliant clamp (the SPB patch test's +3 %, docs/studies.md). The clamp gives each
such particle p the bonds it would have to a body continued through the wall by the odd
extension u(X') = -u(R X'), R the reflection in the wall plane (the classical image of a
fixed end: the displacement vanishes on the wall and a displacement linear in the distance
from the wall continues as the same line):

    ghost q' of q (q = p itself or an intact partner of p):
        X_q' = R X_q,   x_q' = X_q' - (x_q - X_q),   w' = beta(|X_q' - X_p|) omega(...)
    a ghost exists where |X_q' - X_p| < delta + s/2 (the PA-HHB family radius); since
    |X_q - X_p| <= |X_q' - X_p| for p and q on the same side, its source q is already in p's
    family, so the ghosts need no search or halo of their own (only the models with history
    keep state for them, in the ghost store below).

p's shape tensor and deformation gradient sum over its ghosts too (K, N of 003 eq. 4.4-4.5),
and each ghost bond adds to p's force the correspondence pair force of
`correspondence._pair_force` with the ghost's state taken from its source: A_q' = A_q and
F_q' = I - (F_q - I) R (the odd extension's gradient). Both are exact where q's family is
mirror-symmetric along the wall and its displacement gradient is normal to the wall, which a
clamp imposes on the wall itself. The ghost's reaction goes to the wall, not to a particle:
momentum is not conserved near a clamp, as at any support. A ghost bond is intact while its
source bond is; it does not break by its own stretch (the wall is glued) and does not count
in the damage. A ghost bond is not tested against pre-cracks (its source bond was).

The bond-based and LPS models take the same ghost bonds: PMB's pair force needs no ghost
state (pmb.py); LPS's needs the ghost's dilatation, summed over the image of its source's
family (lps.py). With them, a clamped PMB or LPS body is the body continued through the wall
by the odd extension, exactly, under any displacement (tests/unit/test_pd_clamp.py).

The bond-energy model (bond_energy.py) takes F_p over the ghost bonds as correspondence does,
the ghost's F_q' = I - (F_q - I) R and active flag from its source, and the ghost's mean bond
stretch summed over the image of its source's family as LPS's dilatation
(`ghost_stretch_sums`, shared by both). With bond plasticity each ghost bond has its own
plastic stretch, which is history, not a function of the source's: one per clamping face
for the ghost of each half-bond's partner and of the particle itself, in the ghost store
(`ghost_store`: a side structure laid out as the bonds, which migrates and checkpoints with
them, with entries only for the particles within reach of a clamped wall). A clamped
bond-energy body is the continued body exactly under
displacements that depend on the distance from the wall only, and its plastic return under
any displacement (the return reads no F).

The viscoelastic LPS (viscoelastic_lps.py) is linearized about the lengths of the last step,
so every length in a ghost's sums is history: each ghost bond keeps its reference length and
stored isotropic and deviatoric forces, and for the ghost's own m and theta (summed over the
image of its source's family, as LPS's) the previous lengths of that family's bonds (the
images of the source's bonds and of its ghost bonds; under the odd extension they are not
the source bonds' lengths). A clamped viscoelastic body follows the continued body exactly
under any motion.

Users: the SPB coupling (spb.py; ``failure.clamp``) and integral-based bodies of every model
(``type = "peridynamic"``, ``integration = "grid"``; the material's ``clamp``
key, with the walls its bodies start within reach of: `faces_within_reach`). The kernels
take the clamp as ``clamp_parameters``: the horizon, the particle spacing, the influence
function and whether partial volumes are on, so that a ghost's weight follows the rule its
source family was built with (families.py).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .bonds import Bonds
from .families import family_radius, influence, partial_volume
from .geometry import norm3

NO_FACES = np.zeros((0, 2))
NO_CLAMP = np.zeros(4)
LINEAR_INFLUENCE = -1      # SPB's omega = |X| / delta (not one of families.INFLUENCES)


def clamp_parameters(delta: float, spacing: float, influence_code: int,
                     partial_volumes: bool) -> np.ndarray:
    """The kernels' clamp array: horizon, particle spacing, influence (a families.INFLUENCES
    index, or LINEAR_INFLUENCE) and 1.0 where partial volumes are on."""
    return np.array([delta, spacing, float(influence_code), float(partial_volumes)])


@njit(cache=True, error_model="numpy")
def clamp_reach(clamp):
    """Distance from a wall within which a particle has ghost bonds: its family radius."""
    return family_radius(clamp[0], clamp[1], clamp[3] != 0.0)


def sticky_faces(scene) -> np.ndarray:
    """(axis, plane coordinate) of the scene's sticky domain faces that are not periodic."""
    faces = []
    for face, spec in enumerate(scene.walls.faces):
        axis, upper = divmod(face, 2)
        if axis in scene.periodic or spec.condition != "sticky":
            continue
        faces.append((axis, (scene.domain_hi if upper else scene.domain_lo)[axis]))
    return np.array(faces, dtype=np.float64).reshape(-1, 2)


def face_names(faces: np.ndarray, scene) -> list[str]:
    """The scene's names of the walls in ``faces`` (x_lower, y_upper, ...)."""
    from ..scene import FACE_NAMES

    return [FACE_NAMES[2 * int(axis) + (plane == scene.domain_hi[int(axis)])]
            for axis, plane in faces]


def ghost_store(bonds: Bonds, near: np.ndarray, state_names) -> Bonds:
    """The history of the ghost bonds, kept only where there are ghost bonds: a side
    structure in the layout of `Bonds` (it migrates, is realigned and checkpoints as bonds
    do), whose segment for a row in ``near`` holds one entry per ghost source (`ghost_source`:
    the particle's own image first, then the ghosts of its half-bonds in segment order) and
    whose segment for any other row is empty. An entry's ``partner`` is its position in the
    segment (0: the own image), which keeps the order through a checkpoint; the kernels find
    p's entry for source k at ``k + ghost_shift(...)[p]``. The state arrays ``state_names``
    start at 0."""
    counts = np.where(near, bonds.counts() + 1, 0).astype(np.int64)
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    total = int(offsets[-1])
    position = np.arange(total, dtype=np.int64) - np.repeat(offsets[:-1], counts)
    return Bonds(offsets, position, np.zeros(total),
                 state={k: np.zeros(total) for k in state_names})


def ghost_shift(ghosts: Bonds, bonds: Bonds) -> np.ndarray:
    """Per row, the shift from a ghost source index k (offsets[p] - 1 .. offsets[p + 1] - 1)
    to its entry in the ghost store (`ghost_store`); meaningless for rows without ghosts,
    whose entries the kernels never read (`near_a_face`)."""
    return ghosts.offsets[:-1] + 1 - bonds.offsets[:-1]


def attach_ghost_store(pts, faces: np.ndarray, clamp: np.ndarray, state_names) -> None:
    """A model's `setup`: the ghost store of the owned points of ``pts`` (integrator.PDPoints)
    with the states ``state_names``, unless it has none to keep or one came with the points
    (restored from a checkpoint)."""
    if state_names and pts.ghosts is None:
        near = near_rows(pts.x0, pts.n_owned, faces, clamp)
        pts.ghosts = ghost_store(pts.bonds, near, state_names)


NO_GHOST_STATE = (np.empty(0),)
NO_SHIFT = np.empty(0, np.int64)


def ghost_arrays(pts, state_names) -> tuple[tuple, np.ndarray]:
    """The ghost store's arrays ``state_names`` in that order and the shift to an entry
    (`ghost_shift`), as the kernels take them; placeholders they never read when the model
    keeps no ghost state."""
    if not state_names:
        return NO_GHOST_STATE, NO_SHIFT
    return (tuple(pts.ghosts.state[k] for k in state_names),
            ghost_shift(pts.ghosts, pts.bonds))


def share_within_reach(faces: np.ndarray, boxes, reach: float) -> float:
    """The fraction of the bounding boxes' volume within ``reach`` of one of ``faces``
    (particles fill a body evenly: the share of them with ghost bonds)."""
    total = inside = 0.0
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        volume = float(np.prod(hi - lo))
        share = 0.0
        for axis, plane in faces:
            a = int(axis)
            near = min(hi[a], plane + reach) - max(lo[a], plane - reach)
            share += max(near, 0.0) / (hi[a] - lo[a]) if hi[a] > lo[a] else 1.0
        total += volume
        inside += volume * min(share, 1.0)
    return inside / total if total > 0.0 else 0.0


def faces_within_reach(faces: np.ndarray, boxes, reach: float) -> np.ndarray:
    """The rows of ``faces`` that one of the bounding boxes ``boxes`` ((lower, upper) pairs)
    comes within ``reach`` of: a body farther from a wall than its family radius gets no
    ghost bonds there, so it need not carry the clamp's state or work for that wall."""
    keep = []
    for k, (axis, plane) in enumerate(faces):
        a = int(axis)
        for lo, hi in boxes:
            gap = 0.0 if lo[a] <= plane <= hi[a] else min(abs(lo[a] - plane),
                                                          abs(hi[a] - plane))
            if gap < reach:
                keep.append(k)
                break
    return np.ascontiguousarray(faces[keep], dtype=np.float64).reshape(-1, 2)


@njit(cache=True, error_model="numpy", inline="always")
def near_a_face(x0, p, faces, clamp):
    """Whether p starts within a family radius of one of ``faces`` (only then has it ghost
    bonds): the kernels test this before calling into the ghost code, whose calls with many
    arguments cost more than the test for the far points."""
    reach = clamp_reach(clamp)
    for fc in range(faces.shape[0]):
        if abs(x0[p, int(faces[fc, 0])] - faces[fc, 1]) < reach:
            return True
    return False


@njit(cache=True, error_model="numpy")
def near_rows(x0, n, faces, clamp):
    """Mask of the first ``n`` points of ``x0`` that have ghost bonds (`near_a_face`): the
    rows the ghost store keeps entries for, by the kernels' own test."""
    out = np.zeros(n, dtype=np.bool_)
    for p in range(n):
        out[p] = near_a_face(x0, p, faces, clamp)
    return out


@njit(cache=True, error_model="numpy")
def ghost_source(offsets, status, slot, p, k):
    """The k-th ghost source of p, k in offsets[p] - 1 .. offsets[p + 1] - 1: p itself
    (k = offsets[p] - 1), else the partner of bond k; -1 when that bond is broken or its
    partner is not in the halo."""
    if k < offsets[p]:
        return p
    if status[k] == 0 or slot[k] < 0:
        return -1
    return slot[k]


@njit(cache=True, error_model="numpy")
def ghost_at(x, x0, offsets, slot, status, p, k, axis, plane, clamp, Y, X):
    """The ghost of p with source k (`ghost_source`) across the plane x_axis = plane: its
    Y, X into the scratch (`ghost_bond`) and (source, weight w' of `ghost_weight`); weight 0
    where there is none (source broken or out of the halo, or beyond the family radius)."""
    q = ghost_source(offsets, status, slot, p, k)
    if q < 0:
        return q, 0.0
    ghost_bond(x, x0, p, q, axis, plane, x.shape[1], Y, X)
    return q, ghost_weight(X, clamp)


@njit(cache=True, error_model="numpy")
def ghost_bond(x, x0, p, q, axis, plane, dim, Y, X):
    """Y, X (length 3) of the bond from p to the ghost of q across the plane x_axis = plane
    (module docstring)."""
    for i in range(3):
        if i < dim:
            u = x[q, i] - x0[q, i]
            Xq = 2.0 * plane - x0[q, i] if i == axis else x0[q, i]
            X[i] = Xq - x0[p, i]
            Y[i] = Xq - u - x[p, i]
        else:
            X[i] = 0.0
            Y[i] = 0.0


@njit(cache=True, error_model="numpy")
def ghost_scratch(offsets, faces):
    """Scratch for `ghost_family`: X, Y (m, 3), w (m,), src (m,) with m one more than the
    longest bond segment (m = 1 without faces: the kernels then never call it)."""
    most = 0
    if faces.shape[0] > 0:
        for p in range(len(offsets) - 1):
            most = max(most, offsets[p + 1] - offsets[p])
    return (np.empty((most + 1, 3)), np.empty((most + 1, 3)), np.empty(most + 1),
            np.empty(most + 1, np.int64))


@njit(cache=True, error_model="numpy")
def ghost_family(x, x0, offsets, slot, status, p, axis, plane, clamp, X, Y, w, src):
    """p's ghost bonds across the plane x_axis = plane (module docstring), in the order of
    their sources (p itself, then its bonds): X[g], Y[g] (`ghost_bond`), weight w[g] > 0
    (`ghost_weight`) and source src[g]. Returns their count; none where p is out of reach."""
    if abs(x0[p, axis] - plane) >= clamp_reach(clamp):
        return 0
    dim = x.shape[1]
    n = 0
    for k in range(offsets[p] - 1, offsets[p + 1]):
        q = ghost_source(offsets, status, slot, p, k)
        if q < 0:
            continue
        ghost_bond(x, x0, p, q, axis, plane, dim, Y[n], X[n])
        wq = ghost_weight(X[n], clamp)
        if wq == 0.0:
            continue
        w[n] = wq
        src[n] = q
        n += 1
    return n


@njit(cache=True, error_model="numpy")
def ghost_weight(X, clamp):
    """w' of a ghost bond with reference vector X, by the rule of the source family
    (families.find_families: influence times partial volume); 0 outside the family radius."""
    delta, spacing, code, partial = clamp[0], clamp[1], int(clamp[2]), clamp[3] != 0.0
    r = norm3(X[0], X[1], X[2])
    if partial:
        if r >= delta + 0.5 * spacing:
            return 0.0
    elif r > delta:
        return 0.0
    w = partial_volume(r, delta, spacing, partial)
    if code == LINEAR_INFLUENCE:
        return w * r / delta
    return influence(code, r, delta) * w


@njit(cache=True, error_model="numpy")
def image_length(x, x0, p, r, axis, dim):
    """|Y'| of the image p'-r' of the bond p-r across a wall normal to ``axis``:
    Y' = R X - (u_r - u_p) (the odd extension; module docstring)."""
    y2 = 0.0
    for i in range(dim):
        Xi = x0[r, i] - x0[p, i]
        yi = (-Xi if i == axis else Xi) - ((x[r, i] - x0[r, i]) - (x[p, i] - x0[p, i]))
        y2 += yi * yi
    return math.sqrt(y2)


@njit(cache=True, error_model="numpy")
def ghost_stretch_sums(x, x0, vol, offsets, slot, status, weight, p, axis, plane, clamp,
                       ghosts, X, Y, num, den):
    """The bond-stretch sums of p across the face x_axis = plane, for the dilatation of LPS
    and the mean bond stretch of the bond-energy model: p's ghost bonds added to the running
    sums ``num`` (sum w' |X'| (|Y'| - |X'|) V_q) and ``den`` (sum w' |X'|^2 V_q), and
    ``image``, the same numerator over the family of p's image p' across the face (p's
    intact bonds seen from p': X' = R X, Y' = R X - (u_r - u_p); and the images r-p' of its
    ghost bonds p-r', the same reference length, the Y of `ghost_bond` with the roles
    swapped). The image family is the mirror of p's, so its denominator is p's own.
    Returns (num, den, image, ng); image is 0 where p has no ghost bond there (ng = 0).
    ``ghosts``: `ghost_scratch`; X, Y: scratch of length 3."""
    GX, GY, GW, GQ = ghosts
    ng = ghost_family(x, x0, offsets, slot, status, p, axis, plane, clamp, GX, GY, GW, GQ)
    if ng == 0:
        return num, den, 0.0, 0
    dim = x.shape[1]
    image = 0.0
    for b in range(offsets[p], offsets[p + 1]):
        r = slot[b]
        if status[b] == 0 or r < 0:
            continue
        x2 = 0.0
        for i in range(dim):
            Xi = x0[r, i] - x0[p, i]
            x2 += Xi * Xi
        xl = math.sqrt(x2)
        image += weight[b] * xl * (image_length(x, x0, p, r, axis, dim) - xl) * vol[r]
    for g in range(ng):
        r = GQ[g]
        xl = norm3(GX[g, 0], GX[g, 1], GX[g, 2])
        num += GW[g] * xl * (norm3(GY[g, 0], GY[g, 1], GY[g, 2]) - xl) * vol[r]
        den += GW[g] * xl * xl * vol[r]
        ghost_bond(x, x0, r, p, axis, plane, dim, Y, X)
        image += GW[g] * xl * (norm3(Y[0], Y[1], Y[2]) - xl) * vol[r]
    return num, den, image, ng

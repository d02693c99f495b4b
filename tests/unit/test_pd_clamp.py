"""The peridynamic clamp at a sticky wall (hpcmpm/pd/clamp.py): under a displacement that
vanishes on the wall and is linear in the distance from it, a particle next to the wall is
as balanced as an interior one when it is bonded to the mirror image of its family, and is
not without it."""

import math

import numpy as np
import pytest

from hpcmpm.materials.linear_elastic import _stress_2d, _stress_3d
from hpcmpm.pd.clamp import NO_CLAMP, NO_FACES, clamp_parameters
from hpcmpm.pd.correspondence import (correspondence_force_state, correspondence_forces,
                                      correspondence_kinematics)
from hpcmpm.pd.families import INFLUENCES, find_families

DELTA = 3.015          # horizon in spacings (the default)
PLANE = -2.0           # the wall x_0 = PLANE; the first particle row half a spacing off it


def lattice(dim):
    """A cubic lattice of unit spacing starting half a spacing from the wall, wide enough
    along the wall that the middle columns are 2 horizons from every other surface."""
    normal = np.arange(10) + PLANE + 0.5
    along = np.arange(15 if dim == 3 else 17, dtype=float)
    axes = [normal] + [along] * (dim - 1)
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)


def forces(x0, x, clamped, influence="constant", partial_volumes=True, ghost_rule=None):
    """Correspondence forces on the lattice; ``ghost_rule`` (influence, partial volumes) of
    the ghost bonds, by default the family's own."""
    n, dim = x0.shape
    fam = find_families(x0, np.arange(n, dtype=np.int64), n, 1.0, DELTA, influence=influence,
                        partial_volumes=partial_volumes)
    b = fam.bonds
    vol = np.ones(n)
    F, Kinv, A = np.empty((n, dim, dim)), np.empty((n, dim, dim)), np.empty((n, dim, dim))
    active = np.empty(n)
    faces = np.array([[0.0, PLANE]]) if clamped else NO_FACES
    rule = ghost_rule or (influence, partial_volumes)
    clamp = clamp_parameters(DELTA, 1.0, INFLUENCES.index(rule[0]), rule[1]) if clamped \
        else NO_CLAMP
    status = b.status.copy()
    correspondence_kinematics(x, x0, vol, b.offsets, b.slot, status, b.weight, math.inf, n,
                              F, Kinv, active, faces, clamp)
    tau = np.empty_like(F)
    (_stress_3d if dim == 3 else _stress_2d)(F, tau, 1.0, 1.5)
    correspondence_force_state(F, Kinv, tau, active, n, A)
    f = np.empty((n, dim))
    correspondence_forces(x, x0, vol, b.offsets, b.slot, status, b.weight, A, F, active, 0.1,
                          n, f, faces, clamp)
    # The magnitudes of a particle's terms summed, 2 |A| sum_q w |X| V V: round-off in f is
    # a few eps of it (the scale the residual forces are measured against).
    owner = np.repeat(np.arange(n), b.counts())
    lengths = np.linalg.norm(x0[b.slot] - x0[owner], axis=1)
    scale = 2 * np.abs(A).max() * np.bincount(owner, b.weight * lengths, minlength=n).max()
    return F, f, scale


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("g", [(0.01, 0.0, 0.0), (0.0, 0.02, 0.0), (0.01, -0.02, 0.005)])
def test_clamped_wall_rows_are_balanced_under_a_field_zero_on_the_wall(dim, g):
    """u = g (x_0 - PLANE): stretch normal to the wall, shear along it, or both (the only
    linear fields a clamp allows). With the clamp, every particle within a horizon of the
    wall and 2 horizons from the other surfaces feels no force, to round-off (1e-12 of the
    summed magnitudes of its 30-120 bond terms, ~1e-16 each); its F is exact (the
    correspondence fit of an affine field). Without the clamp the rows by the wall are
    pulled into the body by the bonds the wall cut (over 1 % of that sum)."""
    x0 = lattice(dim)
    grad = np.zeros((dim, dim))
    grad[:, 0] = g[:dim]
    x = x0 + np.outer(x0[:, 0] - PLANE, g[:dim])
    mid = x0[:, 1:].mean(axis=0)
    check = (x0[:, 0] - PLANE < DELTA) & np.all(np.abs(x0[:, 1:] - mid) < 1.0, axis=1)
    assert check.sum() == 3        # the middle column's first three rows
    F, f, scale = forces(x0, x, clamped=True)
    np.testing.assert_allclose(F[check], np.broadcast_to(np.eye(dim) + grad, F[check].shape),
                               rtol=0, atol=1e-13)
    assert np.abs(f[check]).max() < 1e-12 * scale
    _, f_cut, _ = forces(x0, x, clamped=False)
    assert np.abs(f_cut[check]).max() > 0.01 * scale


def test_ghost_bonds_follow_their_source_bond():
    """Breaking every bond of the wall row leaves it only its own mirror image: its ghost
    set shrinks with its family (a ghost is intact while its source bond is)."""
    x0 = lattice(2)
    n = len(x0)
    fam = find_families(x0, np.arange(n, dtype=np.int64), n, 1.0, DELTA)
    b = fam.bonds
    row = np.flatnonzero(x0[:, 0] == PLANE + 0.5)
    status = b.status.copy()
    for p in row:
        status[b.offsets[p]:b.offsets[p + 1]] = 0
    F, Kinv, active = np.empty((n, 2, 2)), np.empty((n, 2, 2)), np.empty(n)
    correspondence_kinematics(x0, x0, np.ones(n), b.offsets, b.slot, status, b.weight,
                              math.inf, n, F, Kinv, active, np.array([[0.0, PLANE]]),
                              clamp_parameters(DELTA, 1.0, 0, True))
    # one ghost bond (to its own image, along the normal) spans one direction only
    assert not active[row].any()
    assert active[np.flatnonzero(x0[:, 0] == PLANE + 1.5)].all()


@pytest.mark.parametrize("influence, partial_volumes",
                         [("conical", True), ("inverse", False), ("gaussian", False)])
def test_ghost_weights_follow_the_family_rule(influence, partial_volumes):
    """The integral-based correspondence bodies take the clamp with any influence function
    and with partial volumes on or off: a ghost bond weighs as its source family's bonds do
    (families.find_families), which keeps the wall rows balanced to round-off under the
    clamp's fields. A ghost weighed by another rule (constant, partial volumes on: the SPB
    default) leaves them a force of over 0.1 % of their summed bond terms."""
    x0 = lattice(2)
    x = x0 + np.outer(x0[:, 0] - PLANE, (0.01, -0.02))
    mid = x0[:, 1].mean()
    check = (x0[:, 0] - PLANE < DELTA) & (np.abs(x0[:, 1] - mid) < 1.0)
    _, f, scale = forces(x0, x, True, influence, partial_volumes)
    assert np.abs(f[check]).max() < 1e-12 * scale
    _, f_other, _ = forces(x0, x, True, influence, partial_volumes,
                           ghost_rule=("constant", True))
    assert np.abs(f_other[check]).max() > 1e-3 * scale


def bond_model(name, dim, clamped, influence="constant", partial_volumes=True):
    """A PMB or LPS model (moduli of no consequence here), with the clamp at x_0 = PLANE."""
    from hpcmpm.pd.lps import LPS
    from hpcmpm.pd.pmb import PMB

    faces = np.array([[0.0, PLANE]]) if clamped else NO_FACES
    clamp = clamp_parameters(DELTA, 1.0, INFLUENCES.index(influence), partial_volumes) \
        if clamped else NO_CLAMP
    if name == "pmb":
        return PMB(1.3, math.inf, faces, clamp)
    return LPS(1.0, 0.7 if dim == 3 else 0.6, math.inf, 0.0, faces, clamp)


def bond_forces_and_energy(model, x0, x, influence="constant", partial_volumes=True):
    """Forces and energy densities of every point of a body whose points are all owned, and
    the largest sum over a point's bonds of its bond terms' magnitudes (the scale round-off
    in a force is measured against)."""
    from hpcmpm.pd.integrator import PDPoints
    from hpcmpm.pd.lps import lps_bond_forces
    from hpcmpm.pd.pmb import pmb_bond_forces

    n, dim = x0.shape
    fam = find_families(x0, np.arange(n, dtype=np.int64), n, 1.0, DELTA, influence=influence,
                        partial_volumes=partial_volumes)
    b = fam.bonds
    pts = PDPoints(x0, x, np.ones(n), np.arange(n, dtype=np.int64), n, b)
    model.setup(pts)
    model.update_state(pts)
    f = np.zeros((n, dim))
    model.forces(pts, f)
    terms = np.zeros((len(b.slot), dim))
    if model.name == "pmb":
        pmb_bond_forces(x, x0, pts.vol, b.offsets, b.slot, b.status, b.weight, model.c, n,
                        terms)
    else:
        lps_bond_forces(x, x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                        pts.fields["m"], model.theta, model.kappa, model.mu, n, terms)
    owner = np.repeat(np.arange(n), b.counts())
    scale = np.bincount(owner, np.linalg.norm(terms, axis=1), minlength=n).max()
    return f, model.energy_density(pts), scale, (model, pts)


@pytest.mark.parametrize("name", ["pmb", "lps"])
@pytest.mark.parametrize("dim, influence, partial_volumes",
                         [(2, "constant", True), (3, "constant", True), (2, "conical", False),
                          (2, "gaussian", True)])
def test_clamped_body_equals_the_body_continued_through_the_wall(name, dim, influence,
                                                                 partial_volumes):
    """PMB and LPS: the clamp's ghost bonds are exactly the bonds to the odd extension of the
    body through the wall. Under a random displacement (not zero on the wall: the identity
    holds for any field), the forces and energy densities of the clamped body equal, point
    by point, those of the same body with its mirror image as real points (X' = R X,
    u' = -u, no clamp). For LPS this checks the ghost's dilatation summed over the image of
    its source's family (lps.py): taking the source's own dilatation instead misses by over
    0.1 % of the bond sums. Tolerance: 1e-12 of a point's summed bond magnitudes (measured
    ~1e-15: the two bodies sum the same terms in another order)."""
    rng = np.random.default_rng(7)
    x0 = lattice(dim)
    if dim == 3:        # a thinner 3D lattice keeps the mirrored body's family search fast
        x0 = x0[x0[:, 0] < PLANE + 6]
    n = len(x0)
    u = 0.01 * rng.standard_normal(x0.shape)
    rule = (influence, partial_volumes)
    f, W, _, (model, pts) = bond_forces_and_energy(bond_model(name, dim, True, *rule), x0,
                                                   x0 + u, *rule)
    mirror = x0.copy()
    mirror[:, 0] = 2 * PLANE - mirror[:, 0]
    both0 = np.concatenate([x0, mirror])
    f2, W2, scale, _ = bond_forces_and_energy(bond_model(name, dim, False), both0,
                                              both0 + np.concatenate([u, -u]), *rule)
    f2, W2 = f2[:n], W2[:n]
    assert np.abs(f - f2).max() < 1e-12 * scale
    assert np.abs(W - W2).max() < 1e-12 * np.abs(W2).max()
    near = x0[:, 0] - PLANE < DELTA + 0.5
    # Without the clamp the wall rows miss their cut bonds: not the continued body.
    f_cut, _, _, _ = bond_forces_and_energy(bond_model(name, dim, False), x0, x0 + u, *rule)
    assert np.abs(f_cut - f2)[near].max() > 1e-2 * scale
    if name == "lps":
        rows = near & (model.theta_image[:n, 0] != 0)
        model.theta_image[rows, 0] = model.theta[rows]
        f_naive = np.zeros_like(f)
        model.forces(pts, f_naive)
        assert np.abs(f_naive - f2).max() > 1e-3 * scale


def test_a_wall_beyond_every_body_reach_gets_no_clamp():
    """`faces_within_reach`: a wall is kept when a body's bounding box comes closer to it
    than the family radius (or straddles its plane), dropped otherwise, so a body that
    starts away from every sticky wall runs no clamp kernels and refreshes no image
    dilatations."""
    from hpcmpm.pd.clamp import faces_within_reach

    faces = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]])
    box = ((0.02, 0.3), (0.5, 0.96))                 # 0.02 from x = 0, 0.04 from y = 1
    np.testing.assert_array_equal(faces_within_reach(faces, [box], 0.035), faces[[0]])
    np.testing.assert_array_equal(faces_within_reach(faces, [box], 0.045), faces[[0, 3]])
    far = ((0.4, 0.4), (0.6, 0.6))
    assert faces_within_reach(faces, [far], 0.035).shape == (0, 2)
    np.testing.assert_array_equal(faces_within_reach(faces, [far, box], 0.035), faces[[0]])


def test_clamped_walls_are_named_as_in_the_scene():
    """The run log names the walls a material is clamped at (the default clamp = "auto"
    changes the physics there): ibmpm_bar_2d's sticky fixed end is x_lower, and the other
    sticky faces of a scene map to their own names."""
    from hpcmpm.pd.clamp import face_names, sticky_faces
    from hpcmpm.scene import load_scene

    bar = load_scene("inputs/ibmpm_bar_2d.toml")
    assert face_names(sticky_faces(bar), bar) == ["x_lower"]
    box = load_scene("inputs/ibmpm_disk_impact_2d.toml")   # every wall sticky
    assert face_names(sticky_faces(box), box) == ["x_lower", "x_upper", "y_lower", "y_upper"]

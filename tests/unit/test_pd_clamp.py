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


def bond_energy_model(dim, clamped, psi_p=math.inf):
    """A bond-energy model (moduli of no consequence here), clamped at x_0 = PLANE."""
    from hpcmpm.pd.bond_energy import BondEnergy

    faces = np.array([[0.0, PLANE]]) if clamped else NO_FACES
    clamp = clamp_parameters(DELTA, 1.0, 0, True) if clamped else NO_CLAMP
    return BondEnergy(dim, 1.7, 0.6, 0.9, psi_p, math.inf, 0.0, faces, clamp)


def bond_energy_body(model, x0, x, plastic=None):
    """The model set up on a body whose points are all owned, its real bonds' plastic
    stretches ``plastic(bonds)`` when given; returns (pts, bonds)."""
    from hpcmpm.pd.bond_energy import PLASTIC_STATE
    from hpcmpm.pd.integrator import PDPoints

    n = len(x0)
    b = find_families(x0, np.arange(n, dtype=np.int64), n, 1.0, DELTA).bonds
    pts = PDPoints(x0, x, np.ones(n), np.arange(n, dtype=np.int64), n, b)
    model.setup(pts)
    if plastic is not None:
        b.state[PLASTIC_STATE][:] = plastic(b)
    model.update_state(pts)
    return pts, b


def continued(x0, u):
    """The body and its mirror image through the wall as real points (X' = R X, u' = -u)."""
    mirror = x0.copy()
    mirror[:, 0] = 2 * PLANE - mirror[:, 0]
    both0 = np.concatenate([x0, mirror])
    return both0, both0 + np.concatenate([u, -u])


@pytest.mark.parametrize("dim", [2, 3])
def test_bond_energy_image_stretch_is_the_continued_bodys(dim):
    """The mean bond stretch of a ghost (bond_energy.bond_iso_stretches, the ghosts' e_iso in
    the plastic return) is summed over the image of its source's family: under a random
    displacement it equals the mean stretch of the mirrored point of the continued body, and
    a particle's own mean stretch counts its ghost bonds. Tolerance 1e-13 absolute on
    stretches of order 1e-2 (the two bodies sum the same terms in another order)."""
    rng = np.random.default_rng(11)
    x0 = lattice(dim)
    x0 = x0[x0[:, 0] < PLANE + 6]
    n = len(x0)
    u = 0.01 * rng.standard_normal(x0.shape)
    model = bond_energy_model(dim, True)
    bond_energy_body(model, x0, x0 + u)
    both0, both = continued(x0, u)
    whole = bond_energy_model(dim, False)
    bond_energy_body(whole, both0, both)
    near = x0[:, 0] - PLANE < DELTA - 0.5     # rows with a ghost: d + 1/2 < delta + 1/2
    assert near.sum() > 0.3 * n
    np.testing.assert_allclose(model.eiso[:n], whole.eiso[:n], rtol=0, atol=1e-13)
    np.testing.assert_allclose(model.eiso_image[:n, 0][near], whole.eiso[n:][near], rtol=0,
                               atol=1e-13)
    assert np.all(model.eiso_image[:n, 0][~near] == 0.0)


def pair_value(i, j):
    """A plastic stretch per bond, keyed by the pair of ids (the same value at both ends, as
    the model keeps them), of order 1e-3 and irregular."""
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    return 2e-3 * np.sin(12.9898 * lo + 78.233 * hi) * np.cos(lo - 0.5 * hi)


def ghost_entries(pts, b):
    """Where the clamp's ghost store (clamp.ghost_store) keeps the ghost of each half-bond's
    partner and of each particle itself: indices into its state arrays, -1 for the rows it
    keeps nothing for (beyond reach of the wall)."""
    from hpcmpm.pd.clamp import ghost_shift

    shift = ghost_shift(pts.ghosts, b)
    near = pts.ghosts.counts() > 0
    owner = np.repeat(np.arange(b.n), b.counts())
    bond = np.where(near[owner], np.arange(b.n_bonds) + shift[owner], -1)
    own = np.where(near, b.offsets[:-1] - 1 + shift, -1)
    return bond, own


def plastic_of(b):
    owner = np.repeat(np.arange(b.n), b.counts())
    return pair_value(owner, b.partner)


def clamped_and_continued(dim, u_of, plastic):
    """The clamped bond-energy body and the continued body (`continued`) under the
    displacement u_of(x0), one force pass each. With ``plastic`` every bond starts at
    `pair_value` (the clamped body's ghost bonds at those of the continued body's bonds to
    the image points) and psi_p is the median yield value, so about half the bonds yield."""
    from hpcmpm.pd.bond_energy import mirror_state_names

    x0 = lattice(dim)
    x0 = x0[x0[:, 0] < PLANE + 6]
    n = len(x0)
    u = u_of(x0)
    both0, both = continued(x0, u)
    psi_p = math.inf
    if plastic:
        probe = bond_energy_model(dim, False, 0.0)
        f_yield = probe.yield_values(bond_energy_body(probe, both0, both, plastic_of)[0])
        psi_p = float(np.median(f_yield[np.isfinite(f_yield)]))
    start = plastic_of if plastic else None
    whole = bond_energy_model(dim, False, psi_p)
    pts2, b2 = bond_energy_body(whole, both0, both, start)
    model = bond_energy_model(dim, True, psi_p)
    pts, b = bond_energy_body(model, x0, x0 + u, start)
    if plastic:
        owner = np.repeat(np.arange(n), b.counts())
        ghosts = pts.ghosts.state[mirror_state_names(1)[0]]
        bond, own = ghost_entries(pts, b)
        ghosts[bond[bond >= 0]] = pair_value(owner, n + b.partner)[bond >= 0]
        ghosts[own[own >= 0]] = pair_value(np.arange(n), n + np.arange(n))[own >= 0]
    f = np.zeros((n, dim))
    model.forces(pts, f)
    f2 = np.zeros((2 * n, dim))
    whole.forces(pts2, f2)
    return x0, u, psi_p, (model, pts, f), (whole, pts2, f2[:n])


def assert_ghost_returns_match(n, pts, b, pts2, b2):
    """The clamped body's returned plastic stretches, real and ghost (per half-bond and the
    particle's own image), equal the continued body's on its bonds from real points; and
    many of the ghost bonds yielded (the check is not vacuous). Tolerance 1e-13 absolute on
    stretches of order 1e-3: the two bodies sum the mean stretches in another order, and
    the return (E_dev - sqrt(2 psi_p)) / k amplifies that round-off where E_dev is near the
    yield value (measured up to 1.1e-15)."""
    from hpcmpm.pd.bond_energy import PLASTIC_STATE, mirror_state_names

    after = b2.state[PLASTIC_STATE]
    owner2 = np.repeat(np.arange(b2.n), b2.counts())
    to_image = (owner2 < n) & (b2.partner >= n)
    assert np.mean(after[to_image] != pair_value(owner2, b2.partner)[to_image]) > 0.2
    lookup = {(int(o), int(q)): v for o, q, v in zip(owner2[to_image], b2.partner[to_image],
                                                      after[to_image])}
    owner = np.repeat(np.arange(n), b.counts())
    ghosts = pts.ghosts.state[mirror_state_names(1)[0]]
    bond, own = ghost_entries(pts, b)
    checked = 0
    for k in range(len(b.partner)):
        key = (int(owner[k]), int(n + b.partner[k]))
        if key in lookup:
            assert bond[k] >= 0 and abs(ghosts[bond[k]] - lookup[key]) < 1e-13
            checked += 1
    for p in range(n):
        if (p, n + p) in lookup:
            assert own[p] >= 0 and abs(ghosts[own[p]] - lookup[(p, n + p)]) < 1e-13
            checked += 1
    assert checked == to_image.sum()
    real = (owner2 < n) & (b2.partner < n)
    np.testing.assert_allclose(b.state[PLASTIC_STATE], after[real], rtol=0, atol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("plastic", [False, True])
def test_clamped_bond_energy_body_equals_the_continued_body(dim, plastic):
    """Bond energy with the clamp: under a displacement that depends on the distance from
    the wall only (u = g (X_0 - plane), any direction g: the fields whose odd extension is
    the same field, so the ghost's F_q' = I - (F_q - I) R is exact, as for the
    correspondence clamp), the forces and energy densities of the clamped body equal those
    of the body with its mirror image as real points, point by point, and with plasticity
    so do the returned plastic stretches (`assert_ghost_returns_match`). Tolerance 1e-12 of
    the largest force (a free surface row's, the size of a point's summed bond terms;
    measured ~1e-15)."""
    g = 0.02 * np.random.default_rng(5).standard_normal(dim)
    x0, u, psi_p, (model, pts, f), (whole, pts2, f2) = clamped_and_continued(
        dim, lambda x0: (x0[:, 0] - PLANE)[:, None] * g[None, :], plastic)
    n = len(x0)
    scale = np.abs(f2).max()
    assert np.abs(f - f2).max() < 1e-12 * scale
    W, W2 = model.energy_density(pts), whole.energy_density(pts2)[:n]
    assert np.abs(W - W2).max() < 1e-12 * np.abs(W2).max()
    # Without the clamp the wall rows miss their cut bonds: not the continued body.
    cut = bond_energy_model(dim, False, psi_p)
    pts3, _ = bond_energy_body(cut, x0, x0 + u, plastic_of if plastic else None)
    f3 = np.zeros((n, dim))
    cut.forces(pts3, f3)
    near = x0[:, 0] - PLANE < DELTA + 0.5
    assert np.abs(f3 - f2)[near].max() > 1e-2 * scale
    if plastic:
        assert_ghost_returns_match(n, pts, pts.bonds, pts2, pts2.bonds)


@pytest.mark.parametrize("dim", [2, 3])
def test_clamped_bond_energy_return_follows_the_continued_body(dim):
    """The plastic return of a ghost bond needs no approximation (it reads the stretch and
    the two ends' mean stretches, not F): under a random displacement the returned plastic
    stretches of the clamped body, ghost bonds included, equal the continued body's. This
    is where the ghost's own mean stretch (the image's, not its source's) shows: under the
    fields of the test above the two are equal by symmetry."""
    rng = np.random.default_rng(9)
    x0, _, _, (model, pts, _), (whole, pts2, _) = clamped_and_continued(
        dim, lambda x0: 0.01 * rng.standard_normal(x0.shape), True)
    assert_ghost_returns_match(len(x0), pts, pts.bonds, pts2, pts2.bonds)


def viscoelastic_model(dim, clamped, memory="maxwell"):
    """A viscoelastic LPS (moduli of no consequence here), clamped at x_0 = PLANE."""
    from hpcmpm.pd.viscoelastic_lps import ViscoelasticLPS

    faces = np.array([[0.0, PLANE]]) if clamped else NO_FACES
    clamp = clamp_parameters(DELTA, 1.0, 0, True) if clamped else NO_CLAMP
    model = ViscoelasticLPS(1.0, 0.7 if dim == 3 else 0.6, 0.3, memory, math.inf, 0.0, faces,
                            clamp)
    model.dt = 0.1
    return model


@pytest.mark.parametrize("dim, memory", [(2, "maxwell"), (3, "maxwell"), (2, "none"),
                                         (3, "none")])
def test_clamped_viscoelastic_body_follows_the_continued_body(dim, memory):
    """Viscoelastic LPS with the clamp, over four steps of a random prescribed motion (the
    stored forces, the linearization's reference lengths and the Maxwell decay all carry
    history): at every step the forces of the clamped body equal those of the body with its
    mirror image as real points, point by point, and so do m and theta, and the image's m
    and theta those of the mirrored points. This needs the ghost bonds' own stored forces and
    reference lengths, and the previous lengths of the image family's bonds (module
    docstring of viscoelastic_lps.py). Tolerance 1e-12 of the largest force (measured
    ~1e-15: the same terms in another order)."""
    from hpcmpm.pd.integrator import PDPoints

    rng = np.random.default_rng(13)
    x0 = lattice(dim)
    x0 = x0[x0[:, 0] < PLANE + 6]
    n = len(x0)
    both0, _ = continued(x0, np.zeros_like(x0))

    def body(model, ref):
        k = len(ref)
        b = find_families(ref, np.arange(k, dtype=np.int64), k, 1.0, DELTA).bonds
        pts = PDPoints(ref, ref.copy(), np.ones(k), np.arange(k, dtype=np.int64), k, b)
        model.setup(pts)
        return pts

    model, whole = viscoelastic_model(dim, True, memory), viscoelastic_model(dim, False, memory)
    pts, pts2 = body(model, x0), body(whole, both0)
    # memory = "none" stores no forces, in the ghost store either: lengths only.
    kept = {"mirror_len", "image_mirror_len", "image_len"}
    if memory == "maxwell":
        kept |= {"mirror_iso", "mirror_dev"}
    assert sorted(pts.ghosts.state) == sorted(f"ve_{q}0" for q in kept)
    near = x0[:, 0] - PLANE < DELTA - 0.5          # rows with a ghost bond
    u = np.zeros_like(x0)
    for step in range(4):
        u = u + 0.004 * rng.standard_normal(x0.shape)
        pts.x[:] = x0 + u
        pts2.x[:] = both0 + np.concatenate([u, -u])
        f, f2 = np.zeros((n, dim)), np.zeros((2 * n, dim))
        for m_, p_, f_ in ((model, pts, f), (whole, pts2, f2)):
            m_.update_state(p_)
            m_.forces(p_, f_)
        scale = np.abs(f2).max()
        assert np.abs(f - f2[:n]).max() < 1e-12 * scale, f"step {step}"
        np.testing.assert_allclose(model.m[:n], whole.m[:n], rtol=1e-13)
        np.testing.assert_allclose(model.theta[:n], whole.theta[:n], rtol=0, atol=1e-13)
        np.testing.assert_allclose(model.m_image[:n, 0][near], whole.m[n:][near], rtol=1e-13)
        np.testing.assert_allclose(model.theta_image[:n, 0][near], whole.theta[n:][near],
                                   rtol=0, atol=1e-13)
    # Without the clamp the wall rows miss their cut bonds: not the continued body.
    cut = viscoelastic_model(dim, False, memory)
    pts3 = body(cut, x0)
    pts3.x[:] = x0 + u
    f3 = np.zeros((n, dim))
    cut.update_state(pts3)
    cut.forces(pts3, f3)
    assert np.abs(f3 - f2[:n])[near].max() > 1e-2 * scale

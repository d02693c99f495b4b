"""Uniform deformation: correspondence F, vanishing interior forces, LPS and PMB energy, and
the PMB lattice factors (the issue's 1.059 in 3D, 1.018 in 2D at delta = 3.015 dx)."""

import math

import numpy as np
import pytest

from hpcmpm.pd.correspondence import Correspondence
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS
from hpcmpm.pd.moduli import pmb_micromodulus
from hpcmpm.pd.pmb import PMB, pmb_bond_forces, pmb_energy_density
from pd_helpers import hhb_offsets, lattice, linear_elastic_stress

DELTA = 3.015
K, MU = 2.0, 1.2
RADIUS = DELTA + 0.5


def affine(dim, seed):
    rng = np.random.default_rng(seed)
    return np.eye(dim) + 0.02 * rng.standard_normal((dim, dim))


def model_for(name, dim):
    c = pmb_micromodulus(dim, K, DELTA)
    if name == "pmb":
        return PMB(c)
    if name == "lps":
        return LPS(K, MU)
    lam = K - 2 * MU / dim
    return Correspondence(dim, linear_elastic_stress(dim, MU, lam), 0.1 * c)


@pytest.mark.parametrize("dim", [2, 3])
def test_correspondence_F_equals_affine_F(dim):
    # Jittered points: F = (sum w Y X^T V) K^-1 reproduces any affine map wherever K is
    # invertible, surface points included.
    rng = np.random.default_rng(dim)
    x0, ids = lattice(dim, 12 if dim == 2 else 7)
    x0 += rng.uniform(-0.25, 0.25, x0.shape)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    model = model_for("correspondence", dim)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, model)
    Fa = affine(dim, 7)
    body.pts.x[:] = x0 @ Fa.T + 0.3
    body.compute_forces()
    assert np.all(model.active[: len(x0)] == 1.0)
    # 1e-12: K^-1 of a matrix with condition number < 10 and sums of ~100 terms of O(1).
    assert np.abs(model.F[: len(x0)] - Fa).max() < 1e-12


@pytest.mark.parametrize("name", ["pmb", "lps", "correspondence"])
@pytest.mark.parametrize("dim", [2, 3])
def test_interior_forces_vanish_under_uniform_deformation(name, dim):
    n = 18 if dim == 3 else 20
    x0, ids = lattice(dim, n)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    model = model_for(name, dim)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, model)
    body.pts.x[:] = x0 @ affine(dim, 3).T
    body.compute_forces()
    # Interior: at least 2 (delta + dx/2) from every surface, so the partners' families are
    # complete too (their theta, A enter the force).
    interior = np.all((x0 >= 2 * RADIUS) & (x0 <= n - 1 - 2 * RADIUS), axis=1)
    assert interior.sum() >= 4
    # Scale: the sum of the magnitudes of the pair terms, sum_q |f_pq| ~ stress * V /dx.
    scale = np.abs(body.force).max()
    assert scale > 0
    # 1e-12 of the largest (surface) force: the interior sum cancels ~100-180 terms of that
    # size to round-off.
    assert np.abs(body.force[interior]).max() < 1e-12 * scale


@pytest.mark.parametrize("dim", [2, 3])
def test_lps_energy_under_isotropic_stretch(dim):
    # theta and W are exact for any isotropic stretch; s = 1e-2 because e = |Y| - |X| comes
    # from positions stored to eps |x| ~ 1e-15, a relative error eps |x| / (s |X|) in e.
    s = 1e-2
    x0, ids = lattice(dim, 10 if dim == 3 else 16)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    model = LPS(K, MU)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, model)
    body.pts.x[:] = (1 + s) * x0
    body.compute_forces()
    W = model.energy_density(body.pts)
    want = 4.5 * K * s * s if dim == 3 else 2.0 * K * s * s
    # theta = d s for every family (m is its own normaliser), e^d = 0: exact up to the
    # rounding of two sums of ~100 terms -> 1e-12 relative, at every point (surface too).
    assert np.abs(W / want - 1).max() < 1e-12


def periodic_block(dim, n=8):
    """A fully periodic n^dim lattice (period n > 2 (delta + 1/2) = 7.03): every point has a
    complete family; points at i + 1/2 so that the plane x = n/2 lies between layers."""
    x0, ids = lattice(dim, n, offset=0.5)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA, period=[float(n)] * dim)
    x_all = np.concatenate([x0, x0[fam.image_source] + fam.image_shift])
    return x0, ids, fam, x_all


ISSUE_FACTOR = {3: 1.059, 2: 1.018}


@pytest.mark.parametrize("dim", [2, 3])
def test_pmb_energy_and_flux_lattice_factors(dim):
    s = 2e-3
    n = 8
    x0, ids, fam, x_all = periodic_block(dim, n)
    b = fam.bonds
    c = pmb_micromodulus(dim, K, DELTA)
    vol = np.ones(len(x_all))
    x = (1 + s) * x_all
    W = np.empty(len(x0))
    pmb_energy_density(x, x_all, b.offsets, b.slot, b.status, b.weight, vol, c, len(x0), W)
    fb = np.empty((b.n_bonds, dim))
    pmb_bond_forces(x, x_all, vol, b.offsets, b.slot, b.status, b.weight, c, len(x0), fb)
    owner = np.repeat(np.arange(len(x0)), b.counts())
    crossing = (x_all[owner, 0] < n / 2) & (x_all[b.slot, 0] > n / 2)
    flux = fb[crossing, 0].sum() / n ** (dim - 1)      # force per reference area

    # Independent lattice sums (unit spacing and volume, the closed-form c of the issue).
    xi, r, beta = hhb_offsets(dim, DELTA)
    c_issue = 18 * K / (math.pi * DELTA ** 4) if dim == 3 else 12 * K / (math.pi * DELTA ** 3)
    W_lattice = 0.25 * c_issue * s * s * np.sum(beta * r)
    flux_lattice = c_issue * s * np.sum(np.where(xi[:, 0] > 0, beta * xi[:, 0] ** 2 / r, 0))
    W_continuum = 4.5 * K * s * s if dim == 3 else 2.0 * K * s * s
    # The continuum traction of an isotropic stretch: 3 K s (3D), 2 kappa s (2D).
    flux_continuum = 3 * K * s if dim == 3 else 2 * K * s
    # 1e-10: the same quantity summed in another order over ~180 bonds (round-off ~1e-14).
    assert np.abs(W / W_lattice - 1).max() < 1e-10
    assert flux / flux_lattice == pytest.approx(1, abs=1e-10)
    factor = W_lattice / W_continuum
    assert flux_lattice / flux_continuum == pytest.approx(factor, rel=1e-12)
    # The issue's three-digit factors (delta = 3.015 dx, partial volumes PA-HHB).
    assert round(factor, 3) == ISSUE_FACTOR[dim]

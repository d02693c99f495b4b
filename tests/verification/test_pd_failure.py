"""Failure (003 eq. 4.8): a bond breaks in the first step its stretch exceeds s0, at both
ends; the energy to break every bond across a plane against G0."""


import numpy as np
import pytest

from hpcmpm.pd import moduli
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody
from hpcmpm.pd.lps import LPS
from hpcmpm.pd.correspondence import Correspondence
from hpcmpm.pd.pmb import PMB
from pd_helpers import hhb_offsets, lattice, linear_elastic_stress

DELTA = 3.015
S0 = 0.01


def make_model(name, dim):
    if name == "pmb":
        return PMB(1.0, S0)
    if name == "lps":
        return LPS(1.0, 0.5, S0)
    return Correspondence(dim, linear_elastic_stress(dim, 0.5, 0.3), 0.1, S0)


@pytest.mark.parametrize("name,dim", [("pmb", 2), ("lps", 2), ("correspondence", 2),
                                      ("pmb", 3)])
def test_bond_breaks_in_the_first_step_its_stretch_exceeds_s0(name, dim):
    rng = np.random.default_rng(11)
    x0, ids = lattice(dim, 10 if dim == 2 else 6)
    x0 += rng.uniform(-0.2, 0.2, x0.shape)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, make_model(name, dim))
    b = fam.bonds
    owner = np.repeat(np.arange(len(x0)), b.counts())
    X = x0[b.slot] - x0[owner]
    steps = 40
    # A prescribed homogeneous ramp (stretch along x, shear): each bond's stretch grows
    # monotonically at its own rate.
    G = np.zeros((dim, dim))
    G[0, 0], G[0, 1] = 1.0, 0.6
    expected = np.full(b.n_bonds, -1)
    margin = np.inf
    for n in range(1, steps + 1):
        Fn = np.eye(dim) + 5e-4 * n * G
        Y = X @ Fn.T
        s = np.linalg.norm(Y, axis=1) / np.linalg.norm(X, axis=1) - 1
        margin = min(margin, np.abs(s - S0).min())
        expected[(expected < 0) & (s > S0)] = n
    # No stretch within 1e-9 of s0: the kernels' and numpy's rounding cannot disagree.
    assert margin > 1e-9
    got = np.full(b.n_bonds, -1)
    for n in range(1, steps + 1):
        body.pts.x[:] = x0 @ (np.eye(dim) + 5e-4 * n * G).T
        intact = b.status == 1
        body.compute_forces()
        got[intact & (b.status == 0)] = n
    assert (expected > 0).sum() > 0.2 * b.n_bonds       # the ramp breaks many bonds
    assert np.array_equal(got, expected)


# The issue states 1.022 (3D) and 0.991 (2D). PA-HHB at delta = 3.015 dx, the rule that
# reproduces the energy factors 1.059 / 1.018, gives 1.0675 and 1.0304 here; no
# partial-volume rule tried reproduces the figures (none: 1.1195 / 1.0059; LAMMPS's
# truncated rule: 0.8604 / 0.8144; exact cell-ball overlap: 1.0164 / 1.0283), see the report.
HHB_G_FACTOR = {3: 1.0675, 2: 1.0304}


@pytest.mark.parametrize("dim", [2, 3])
def test_energy_to_break_bonds_across_a_plane(dim):
    E, G0, h = 2.0e3, 0.7, 1.0
    nu, plane = (0.25, "strain")
    n = 8
    x0, ids = lattice(dim, n, offset=0.5)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA, period=[float(n)] * dim)
    b = fam.bonds
    x_all = np.concatenate([x0, x0[fam.image_source] + fam.image_shift])
    c = moduli.pmb_micromodulus_from_E(dim, E, nu, DELTA, plane, thickness=h)
    s0 = moduli.critical_stretch_from_moduli(dim, G0, E, nu, DELTA, plane)
    owner = np.repeat(np.arange(len(x0)), b.counts())
    crossing = (x_all[owner, 0] < n / 2) & (x_all[b.slot, 0] > n / 2)
    r = np.linalg.norm(x_all[b.slot] - x_all[owner], axis=1)
    # Each crossing bond stores c w s0^2 |X| / 2 (V_p = V_q = 1) when it breaks.
    G_code = np.sum(0.5 * c * b.weight[crossing] * s0 ** 2 * r[crossing]) / n ** (dim - 1)

    xi, rr, beta = hhb_offsets(dim, DELTA)
    up = xi[:, 0] > 0
    # Pairs crossing a plane per unit area: xi_x of them per offset xi (unit lattice).
    G_lattice = np.sum(0.5 * c * beta[up] * s0 ** 2 * rr[up] * xi[up, 0])
    assert G_code == pytest.approx(G_lattice, rel=1e-10)
    factor = G_lattice / G0
    assert factor == pytest.approx(HHB_G_FACTOR[dim], abs=5e-5)

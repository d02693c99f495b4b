"""Lattices and lattice sums for the PD verification tests, written independently of
hpcmpm.pd (numpy over integer offsets, the PA-HHB rule spelled out here)."""

import itertools

import numpy as np

from hpcmpm.materials.linear_elastic import _stress_2d, _stress_3d


def lattice(dim, n, offset=0.0):
    """Points of an n^dim cubic lattice of unit spacing (row-major), ids 0..n^dim-1."""
    g = np.array(list(itertools.product(range(n), repeat=dim)), dtype=np.float64) + offset
    return g, np.arange(len(g), dtype=np.int64)


def hhb_offsets(dim, delta):
    """Integer lattice offsets xi with 0 < |xi| < delta + 1/2 and their partial-volume
    fraction beta = min(1, delta + 1/2 - |xi|) (unit spacing)."""
    r = int(np.ceil(delta + 0.5))
    xi = np.array(list(itertools.product(range(-r, r + 1), repeat=dim)), dtype=np.float64)
    n = np.linalg.norm(xi, axis=1)
    keep = (n > 0) & (n < delta + 0.5)
    xi, n = xi[keep], n[keep]
    return xi, n, np.minimum(1.0, delta + 0.5 - n)


def linear_elastic_stress(dim, mu, lam):
    """Kirchhoff stress tau(F) of the project's small-strain linear elastic material."""
    kernel = _stress_3d if dim == 3 else _stress_2d
    return lambda F, tau: kernel(np.ascontiguousarray(F), tau, mu, lam)


def half_bond_lists(bonds):
    """(owner row, partner slot) per half-bond."""
    owner = np.repeat(np.arange(bonds.n), bonds.counts())
    return owner, bonds.slot.astype(np.int64)

"""Pieces of the b_E models (hpcmpm/materials/left_cauchy_green.py) against their documented
closed forms: the von Mises radial return on the isochoric strain (Simo 1988), the
admissibility test of b_hat, the Herschel-Bulkley flow factors and the explicit integrator's
time-step bound."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from hpcmpm.materials import make_material
from hpcmpm.materials.left_cauchy_green import HB, admissible, plastic_factors, psi, radial_return


@dataclass
class Spec:
    type: str
    params: dict
    density: float = 2.0
    name: str = "m"


def spd(rng, d: int) -> np.ndarray:
    F = np.eye(d) + 0.4 * rng.normal(size=(d, d))
    return F @ F.T


@pytest.mark.parametrize("d", (2, 3))
def test_radial_return_is_simos(d):
    """radial_return(b_hat, sigma_Y): b_bar = b_hat / det(b_hat)^(1/d); outside the yield
    surface dev b_bar is scaled to |dev b_bar| = sigma_Y along itself, tr b_bar kept; inside
    b_bar is returned as is."""
    rng = np.random.default_rng(d)
    for _ in range(5):
        bh = spd(rng, d)
        bbar = bh / np.linalg.det(bh) ** (1 / d)
        dev = bbar - np.trace(bbar) / d * np.eye(d)
        n = np.linalg.norm(dev)
        # Round-off relative to the largest entry (random b_bar reach ~1e2).
        scale = np.abs(bbar).max()
        for sigma_y in (0.3 * n, 0.7 * n, 0.99 * n):  # outside
            out = np.array(radial_return(tuple(bh.ravel()), sigma_y)).reshape(d, d)
            want = np.trace(bbar) / d * np.eye(d) + sigma_y / n * dev
            assert np.allclose(out, want, rtol=0, atol=1e-13 * scale)
        inside = np.array(radial_return(tuple(bh.ravel()), 1.5 * n)).reshape(d, d)
        assert np.allclose(inside, bbar, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("d", (2, 3))
def test_negative_trace_is_inadmissible(d):
    """admissible(J, det b_hat, tr b_hat) needs all three positive; b = -I in 2D has
    det > 0 but tr < 0, and psi there is +inf (the docstring's "+inf when inadmissible")."""
    assert not admissible(1.0, 1.0, -2.0)
    assert not admissible(1.0, -1.0, 2.0) and not admissible(-1.0, 1.0, 2.0)
    assert admissible(1.0, 1.0, 2.0)
    if d == 2:
        assert psi((-1.0, 0.0, 0.0, -1.0), 1.0, 3.0, 5.0) == math.inf


@pytest.mark.parametrize("name, extra", [("oldroyd_b", {"relaxation_time": 1.0}),
                                         ("von_mises", {"yield_strain": 0.1})])
def test_explicit_time_step_bound_is_cfl_and_viscous(name, extra):
    """largest_time_step under the explicit integrator without dt or max_dt:
    min(cfl dx / c, rho dx^2 / (2 d mu_N)), c = sqrt((lam + 2 mu)/rho)."""
    mu, lam, rho, dx, cfl = 3.0, 5.0, 2.0, 0.01, 0.4
    for mu_n in (0.0, 0.7, 1e-3):
        mat = make_material(Spec(name, {"mu": mu, "lambda": lam, "viscosity": mu_n, **extra}),
                            2)
        scene = SimpleNamespace(dt=None, max_dt=None, integrator="explicit", cfl=cfl, dx=dx)
        want = cfl * dx / math.sqrt((lam + 2 * mu) / rho)
        if mu_n > 0:
            want = min(want, rho * dx * dx / (2 * 2 * mu_n))
        # A few roundings.
        assert mat.largest_time_step(scene) == pytest.approx(want, rel=1e-14)


@pytest.mark.parametrize("d", (2, 3))
@pytest.mark.parametrize("h", (0.6, 1.0, 1.7))
def test_herschel_bulkley_factors_are_the_flow_rule(d, h):
    """plastic_factors(HB) is 000 §4.6.2 as the module docstring writes it:
    gdot = max(0, (|dev b| - sigma_Y)/eta)^(1/h), alpha = (2 dt/d) tr b gdot/|dev b|,
    beta = tr b/d, c = 1/(1 + alpha); S = c (b + alpha beta I), R = B = c b. The states have
    tr b/d from 0.5 to 3 (beta far from 1) and |dev b| above and below sigma_Y."""
    rng = np.random.default_rng(int(10 * h) + d)
    dt, sigma_y, eta = 0.3, 0.2, 0.5
    for scale in (0.5, 1.0, 3.0):
        b = scale * spd(rng, d)
        dev = b - np.trace(b) / d * np.eye(d)
        n = np.linalg.norm(dev)
        gdot = max(0.0, (n - sigma_y) / eta) ** (1 / h)
        alpha = 2 * dt / d * np.trace(b) * gdot / n
        c = 1 / (1 + alpha)
        want_S = c * (b + alpha * np.trace(b) / d * np.eye(d))
        S, R, B = (np.array(x).reshape(d, d) for x in
                   plastic_factors(HB, tuple(b.ravel()), tuple(b.ravel()), tuple(b.ravel()),
                                   dt, 0.0, sigma_y, 1 / h, eta))
        # Round-off relative to |b|.
        tol = 1e-14 * np.abs(b).max()
        assert np.allclose(S, want_S, rtol=0, atol=tol)
        assert np.allclose(R, c * b, rtol=0, atol=tol) and np.allclose(B, c * b, rtol=0, atol=tol)
    below = 0.01 * np.eye(d) + np.eye(d)  # dev b = 0 < sigma_Y: no flow
    S, R, B = plastic_factors(HB, tuple(below.ravel()), tuple(below.ravel()),
                              tuple(below.ravel()), dt, 0.0, sigma_y, 1 / h, eta)
    assert np.array_equal(np.array(S), below.ravel()) and np.array_equal(np.array(R), below.ravel())

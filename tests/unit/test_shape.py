"""B-spline shape functions: partition of unity, linear completeness, gradients."""

import numpy as np
import pytest

from hpcmpm.kernels.shape import CUBIC, QUADRATIC, evaluate

# Sums of a handful of O(1) terms: round-off is a few ulps.
ROUND_OFF = 1e-13


@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
def test_partition_of_unity_and_linear_completeness(order):
    rng = np.random.default_rng(0)
    xi = rng.uniform(-3.0, 7.0, size=(500, 1))
    base, w, dw = evaluate(xi, order, 1.0)
    nodes = base[:, 0, None] + np.arange(order + 1)
    assert np.allclose(w[:, 0].sum(axis=1), 1.0, atol=ROUND_OFF, rtol=0)
    # sum_i w_i x_i = x_p reproduces linear fields exactly.
    assert np.allclose((w[:, 0] * nodes).sum(axis=1), xi[:, 0], atol=1e-12, rtol=0)
    # Gradients of a partition of unity sum to zero; of x_i they sum to one.
    assert np.allclose(dw[:, 0].sum(axis=1), 0.0, atol=ROUND_OFF)
    assert np.allclose((dw[:, 0] * nodes).sum(axis=1), 1.0, atol=1e-12)
    assert np.all(w >= -ROUND_OFF)


@pytest.mark.parametrize("order", [QUADRATIC, CUBIC])
def test_gradient_matches_finite_difference(order):
    rng = np.random.default_rng(1)
    dx = 0.37
    xi = rng.uniform(0.0, 10.0, size=(200, 1))
    h = 1e-6  # in cells; central differences of a C1 piecewise polynomial: error O(h^2)
    base, w, dw = evaluate(xi, order, 1.0 / dx)
    # Evaluate the same nodes' weights at xi +- h; skip points within h of a knot where the
    # stencil base changes.
    bp, wp, _ = evaluate(xi + h, order, 1.0 / dx)
    bm, wm, _ = evaluate(xi - h, order, 1.0 / dx)
    same = (bp[:, 0] == base[:, 0]) & (bm[:, 0] == base[:, 0])
    fd = (wp - wm)[same, 0] / (2 * h * dx)
    # FD error ~ h^2 * N''' / dx plus round-off 1e-16/(h dx): about 1e-9 here.
    assert np.allclose(dw[same, 0], fd, atol=1e-8)
    assert same.sum() > 150

"""Bond geometry shared by every model kernel, and the per-particle bond sums that do not
depend on a model (damage, weighted volume).

Bit-identical ends. Each pair term a kernel adds to particle p is an odd function of the bond
(X, Y) = (x0_q - x0_p, x_q - x_p) whose scalar factors are symmetric in p and q and combined
with commutative operations only (``V_p * V_q``, ``t_p + t_q``, ``A_p X + A_q X``). IEEE
negation of a difference is exact and addition/multiplication are commutative, so the term
that q adds is bitwise the negative of p's, and a bond's stretch is bitwise the same at both
ends: this is the same as evaluating every bond in the orientation lower id -> higher id and
negating, without reading the partner's id. Kernels do not use fastmath (no contraction into
fused multiply-adds, which would break the symmetry) and use numpy's error model (a division
by zero gives inf or nan instead of a per-division check and an exception).

Not across a periodic face: there the partner is an image row holding x + P (and x0 + P),
rounded, while the partner's own rank sees this end as x - P rounded, so the two ends' bond
vectors can differ in their last bit. Momentum then drifts a little faster than the sums'
round-off alone lets it (measured with `integrator.PDBody`: a 12 x 8 PMB strip periodic along
x, moving along x at 10 times its internal velocities, drifts by 3.6e-14 of sum |m (v - u)|
over 500 steps; 2.2e-16 without the periodic axis, 2.0e-16 periodic at rest). Exact there
would need the images' shifts kept apart from their positions and added in `bond_vectors`.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, error_model="numpy")
def bond_vectors(x, x0, p, q, dim):
    """(Y, X) components of the bond p -> q; the third components are 0 in 2D."""
    y0 = x[q, 0] - x[p, 0]
    y1 = x[q, 1] - x[p, 1]
    X0 = x0[q, 0] - x0[p, 0]
    X1 = x0[q, 1] - x0[p, 1]
    if dim == 3:
        y2 = x[q, 2] - x[p, 2]
        X2 = x0[q, 2] - x0[p, 2]
    else:
        y2 = 0.0
        X2 = 0.0
    return y0, y1, y2, X0, X1, X2


@njit(cache=True, error_model="numpy")
def norm3(a, b, c):
    return math.sqrt(a * a + b * b + c * c)


@njit(cache=True, error_model="numpy")
def stretched_past(e, xl, s0):
    """Whether a bond of extension e = |Y| - |X| and reference length xl > 0 has its stretch
    e / |X| past s0 (003 eq. 4.8), tested as e > s0 |X|: no division in the bond loops,
    whose divisions and square roots bound their speed (scripts/bench_pd.py). The same
    (e, xl) at both ends of a bond give the same answer; s0 = inf breaks nothing."""
    return e > s0 * xl


@njit(cache=True, error_model="numpy")
def weighted_volume_sums(x0, vol, offsets, slot, status, weight, n_owned, out):
    """out_p = sum over intact bonds of w_pq V_q (the damage denominator at set-up, 003 eq.
    4.8's phi = 1 - sum_active / sum_initial)."""
    for p in range(n_owned):
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] != 0:
                s += weight[b] * vol[slot[b]]
        out[p] = s


@njit(cache=True, error_model="numpy")
def damage(vol, offsets, slot, status, weight, initial, n_owned, out):
    """phi_p = 1 - sum_active w V_q / sum_initial w V_q (1 for a particle that had none)."""
    for p in range(n_owned):
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] != 0:
                s += weight[b] * vol[slot[b]]
        out[p] = 1.0 - s / initial[p] if initial[p] > 0.0 else 1.0


@njit(cache=True, error_model="numpy")
def break_stretched(x, x0, offsets, slot, status, s0, n_owned):
    """Break every intact bond whose stretch s = (|Y| - |X|)/|X| exceeds s0 (003 eq. 4.8,
    irreversible). Returns the number of half-bonds broken."""
    dim = x.shape[1]
    broken = 0
    for p in range(n_owned):
        for b in range(offsets[p], offsets[p + 1]):
            if status[b] == 0:
                continue
            if slot[b] < 0:         # partner beyond the halo reach (pmb.py)
                status[b] = 0
                broken += 1
                continue
            y0, y1, y2, X0, X1, X2 = bond_vectors(x, x0, p, slot[b], dim)
            xl = norm3(X0, X1, X2)
            if stretched_past(norm3(y0, y1, y2) - xl, xl, s0):
                status[b] = 0
                broken += 1
    return broken

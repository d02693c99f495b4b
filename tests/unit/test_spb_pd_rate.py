"""The PD family's velocity gradient (`correspondence_rate`), which the state update of a
converted shock or j2 particle reads (spb.SPBExtension._pd_velocity_gradient): exact for an
affine motion, the rate the correspondence force works on (sum_p f_p . v_p = -sum_p V_p
P_p : F_dot_p), zero where the family carries no PD stress or degenerates."""

import math

import numpy as np
import pytest

from hpcmpm.materials.linear_elastic import _stress_2d, _stress_3d
from hpcmpm.pd.clamp import NO_CLAMP, NO_FACES
from hpcmpm.pd.correspondence import (correspondence_force_state, correspondence_forces,
                                      correspondence_kinematics, correspondence_rate)
from hpcmpm.pd.families import find_families


def body(dim, seed=0):
    """A perturbed unit lattice (7^3 or 12^2 points), its families (horizon 3.015), volumes
    and a non-affine deformed state."""
    rng = np.random.default_rng(seed)
    n = 7 if dim == 3 else 12
    x0 = np.stack(np.meshgrid(*[np.arange(n, dtype=float)] * dim, indexing="ij"),
                  -1).reshape(-1, dim) + rng.uniform(-0.3, 0.3, (n ** dim, dim))
    fam = find_families(x0, np.arange(len(x0), dtype=np.int64), len(x0), 1.0, 3.015)
    vol = rng.uniform(0.5, 1.5, len(x0))
    x = x0 + 0.05 * rng.standard_normal(x0.shape)
    return rng, x0, fam.bonds, vol, x


def kinematics(x, x0, b, vol):
    n, dim = x0.shape
    F, Kinv, active = np.empty((n, dim, dim)), np.empty((n, dim, dim)), np.empty(n)
    status = b.status.copy()
    correspondence_kinematics(x, x0, vol, b.offsets, b.slot, status, b.weight, math.inf, n,
                              F, Kinv, active, NO_FACES, NO_CLAMP)
    return F, Kinv, active, status


def rate(x_new, x_old, x0, b, status, vol, active, dt):
    n, dim = x0.shape
    L = np.full((n, dim, dim), np.nan)
    correspondence_rate(x_new, x_old, x0, vol, b.offsets, b.slot, status, b.weight, active, n,
                        dt, NO_FACES, NO_CLAMP, L)
    return L


@pytest.mark.parametrize("dim", [2, 3])
def test_rate_of_an_affine_motion_is_exact(dim):
    """x_old = A0 X, x_new = A1 X + c: every family (interior or cut by the surface) gives
    I + dt L = A1 A0^-1 to round-off (1e-12 of |A1 A0^-1|, a few eps per bond sum)."""
    rng, x0, b, vol, _ = body(dim)
    A0 = np.eye(dim) + 0.1 * rng.standard_normal((dim, dim))
    A1 = A0 + 0.02 * rng.standard_normal((dim, dim))
    x_old = x0 @ A0.T
    x_new = x0 @ A1.T + rng.standard_normal(dim)
    _, _, active, status = kinematics(x_old, x0, b, vol)
    dt = 1e-3
    L = rate(x_new, x_old, x0, b, status, vol, active, dt)
    expect = A1 @ np.linalg.inv(A0)
    assert active.all()
    assert np.abs(np.eye(dim) + dt * L - expect).max() < 1e-12 * np.abs(expect).max()


@pytest.mark.parametrize("dim", [2, 3])
def test_the_force_works_on_the_rate(dim):
    """At a non-affine state x with any velocities v, the correspondence force f (no
    stabilization) and the rate of the move x -> x + dt v satisfy sum_p f_p . v_p =
    -sum_p V_p P_p : (L_p F_p) (F is linear in the positions over fixed bonds, so L F is
    F_dot exactly; eq. 4.7 summed by parts): what makes a converted particle's internal
    energy gain exactly the work its bonds do. Round-off: 1e-10 of sum_p |f_p| |v_p|."""
    rng, x0, b, vol, x = body(dim)
    n = len(x0)
    F, Kinv, active, status = kinematics(x, x0, b, vol)
    tau = np.empty_like(F)
    (_stress_3d if dim == 3 else _stress_2d)(F, tau, 0.7, 0.4)
    A = np.empty_like(F)
    correspondence_force_state(F, Kinv, tau, active, n, A)
    f = np.empty((n, dim))
    correspondence_forces(x, x0, vol, b.offsets, b.slot, status, b.weight, A, F, active, 0.0,
                          n, f, NO_FACES, NO_CLAMP)
    v = rng.standard_normal((n, dim))
    dt = 1e-2     # any step: the identity is exact, not first order
    L = rate(x + dt * v, x, x0, b, status, vol, active, dt)
    P = tau @ np.linalg.inv(F).transpose(0, 2, 1)
    internal = np.einsum("p,pij,pij->", vol, P, L @ F)
    external = float(np.sum(f * v))
    scale = float(np.sum(np.linalg.norm(f, axis=1) * np.linalg.norm(v, axis=1)))
    assert abs(external + internal) < 1e-10 * scale


def test_no_rate_where_the_family_carries_no_stress():
    """A detached point (active 0) and one whose intact bonds are all deformed onto a line
    (N singular: its increment would flatten its material state) get L = 0; the others
    theirs."""
    rng, x0, b, vol, x = body(2)
    _, _, active, status = kinematics(x, x0, b, vol)
    middle = int(np.argmin(np.linalg.norm(x0 - x0.mean(axis=0), axis=1)))
    active[0] = 0.0
    x_new = x + 1e-3 * rng.standard_normal(x.shape)
    flat = x_new.copy()
    # every partner of `middle` (and itself) onto the horizontal line through it
    partners = b.slot[b.offsets[middle]:b.offsets[middle + 1]]
    flat[partners, 1] = flat[middle, 1]
    L = rate(x_new, x, x0, b, status, vol, active, 1e-3)
    L_flat = rate(flat, x, x0, b, status, vol, active, 1e-3)
    assert np.all(L[0] == 0.0) and np.all(L_flat[0] == 0.0)
    assert np.all(L_flat[middle] == 0.0) and np.abs(L[middle]).max() > 0.0
    assert np.isfinite(L).all() and np.abs(L[1:]).max(axis=(1, 2)).min() > 0.0

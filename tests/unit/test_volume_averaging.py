"""Volume averaging (``simulation.volume_averaging = "increment"``, hpcmpm/kernels/volume.py):
the kernels' scatter/ratio/gather against the documented formula with a volume V0 that varies
by particle, and the engine's average in a moving scene, where the gather must use the weights
at x^n that the scatter used.

The formula (volume.py's docstring; docs/scene-format.md, ``simulation.volume_averaging``),
with w_ip the B-spline weights of the step's P2G at x^n (000 §3.2, eq. 3.2) and J^{n+1} the
materials' update det(I + dt L) J^n (000 eq. 5.12); the average itself is not in 000 (an F-bar
on the increment, Coombs et al. 2018):

    r_i = sum_p w_ip V0_p J_p^{n+1} / sum_p w_ip V0_p J_p^n,    J_p^{n+1} <- J_p^n sum_i w_ip r_i,

and it conserves the total volume sum_p V0_p J_p by the partition of unity sum_i w_ip = 1:
sum_p V0_p J_p^n sum_i w_ip r_i = sum_i r_i sum_p w_ip V0_p J_p^n = sum_p V0_p J_p^{n+1}.
Both steps of that identity need the same weights w_ip in the scatter and the gather, and the
V0_p in the scatter: with the gather at x^{n+1} or without V0 (a uniform V0, which every scene
has today, hides the latter) the total changes.
"""

from __future__ import annotations

import numpy as np
import pytest

from hpcmpm.kernels.shape import ORDERS
from hpcmpm.kernels.transfer import static
from hpcmpm.kernels.volume import GATHER_VOLUME, SCATTER_VOLUME, nodal_ratio
from hpcmpm.runner import simulate
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation
from volume_reference import reference_average


# -- the kernels, one average ----------------------------------------------------------------
def kernel_average(x, vol0, J_old, J_new, dx, order, shape):
    """The engine's sequence on one block whose first node is node 0: scatter, nodal ratio,
    gather (hpcmpm/simulation.py, `average_volumes`), here at the same x for both."""
    dim = x.shape[1]
    lo, origin = np.zeros(dim), np.zeros(dim, dtype=np.int64)
    grid_old, grid_new = np.zeros(shape), np.zeros(shape)
    SCATTER_VOLUME[dim](x, vol0, J_old, J_new, static(order), dx, lo, origin, grid_old,
                        grid_new)
    nodal_ratio(grid_old.reshape(-1), grid_new.reshape(-1))
    J = J_new.copy()
    GATHER_VOLUME[dim](x, J_old, static(order), dx, lo, origin, grid_new, J)
    return J


@pytest.mark.parametrize("kernel", ["quadratic", "cubic"])
@pytest.mark.parametrize("dim", [2, 3])
def test_average_with_non_uniform_initial_volumes(dim, kernel):
    """Random particles, V0 over a factor 10, J^n and J^{n+1} random: one average conserves
    sum V0 J and equals the formula computed here with numpy (rtol 1e-13: sums of at most
    4^3 = 64 positive terms per node and per particle, in another order; measured <= 8e-16,
    and <= 3e-16 for the total)."""
    rng = np.random.default_rng(12 + dim)
    order = ORDERS[kernel]
    dx = 0.125
    n = 150 if dim == 2 else 400
    # Particles within 1 < x/dx < 5 (a few per cell, so nodes are shared): every stencil
    # lies in nodes 0..7.
    x = dx * rng.uniform(1.0, 5.0, (n, dim))
    vol0 = 10.0 ** rng.uniform(-1.0, 0.0, n) * dx**dim
    J_old = rng.uniform(0.7, 1.3, n)
    J_new = J_old * rng.uniform(0.8, 1.2, n)
    shape = (8,) * dim
    J = kernel_average(x, vol0, J_old, J_new, dx, order, shape)
    expected = reference_average(x, vol0, J_old, J_new, dx, order)
    np.testing.assert_allclose(J, expected, rtol=1e-13, atol=0)
    assert np.sum(vol0 * J) == pytest.approx(np.sum(vol0 * J_new), rel=1e-13)
    # Not vacuous: the average moves J by a sizeable part of the 20 % changes, and weighing
    # by V0 matters (V0 left out of the formula gives other values).
    assert np.abs(J - J_new).max() > 0.05
    unweighted = reference_average(x, np.ones(n), J_old, J_new, dx, order)
    assert np.abs(unweighted - expected).max() > 1e-3


# -- the engine, a moving scene --------------------------------------------------------------
# A jittered block of weakly compressible fluid flying at 2-3 m/s and spinning at 20 rad/s
# (explicit, dx = 1/32): each step moves the particles by about 0.1 dx, and the jitter makes
# the step's change of J vary at the particle scale, so the nodal ratios r_i vary between
# neighbouring nodes and weights at x^{n+1} instead of x^n would not conserve the volume.
MOVING = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.03125
particles_per_cell = 2
kernel = "quadratic"
transfer = "apic"
integrator = "explicit"
volume_averaging = "increment"
end_time = 0.04
gravity = [0.0, -9.81]

[[materials]]
name = "water"
type = "weakly_compressible"
density = 1000.0
E = 1.0e5

[[bodies]]
name = "blob"
material = "water"
shape = "box"
lower = [0.25, 0.25]
upper = [0.5, 0.5]
velocity = [3.0, 2.0]
angular_velocity = 20.0
jitter = 0.5
"""


def test_average_in_a_moving_scene_conserves_the_total_volume(monkeypatch):
    """Every step's average keeps sum_p V0_p J_p to round-off: the gather takes the weights
    at x^n, the positions the scatter used (hpcmpm/simulation.py, `remember_volumes` /
    `average_volumes`), not the moved x^{n+1}. Measured over the 53 steps: at most 4e-16
    relative per step (round-off), the particles moving 0.08-0.14 dx per step; so 1e-13."""
    kept, changes, moved, acted = {}, [], [], []
    remember, average = Simulation.remember_volumes, Simulation.average_volumes

    def remember_volumes(sim):
        kept["x"] = sim.particles["x"].copy()
        remember(sim)

    def average_volumes(sim):
        p = sim.particles
        J_new = p["J"].copy()
        before = np.sum(p["vol0"] * J_new)
        average(sim)
        changes.append(abs(np.sum(p["vol0"] * p["J"]) / before - 1.0))
        moved.append(np.abs(p["x"] - kept["x"]).max() / sim.dx)
        acted.append(np.abs(p["J"] - J_new).max())

    monkeypatch.setattr(Simulation, "remember_volumes", remember_volumes)
    monkeypatch.setattr(Simulation, "average_volumes", average_volumes)
    sim = simulate(parse_scene(MOVING, "moving.toml"))
    assert sim.step_index == len(changes) >= 20
    # Not vacuous: the particles move by a sizeable part of a cell each step, and the
    # average changes J.
    assert min(moved) > 0.05, min(moved)
    assert max(acted) > 1e-6, max(acted)
    assert max(changes) <= 1e-13, max(changes)

"""The linearized semi-implicit solve does not depend on a uniform velocity added to the scene,
and a stiff body in free flight does not have its round-off solved (`SemiImplicitIntegrator._cg`);
nor does Newton with ``solver.newton_stop = "galilean"`` (`_newton_reference`).

A uniform velocity U is in the null space of the elastic part of H (L_p(U) = U sum_i grad w_ip^T
= 0), so b = -P g(v*) and the exact solution less U are the same with and without it. Only the
CG's stop could bring U in, and it did: its floor was tolerance |M v*|, which grows with U. On the
block below, after one step at solver.tolerance 1e-6, v - U differed from the run at rest by
3.2e-4 of the block's own velocities at U = 3 and by 3.3e-2 at U = 300, where the CG stopped at
0 iterations. The floor is now relative to |M (v* - c)|, c the uniform part of v*.
"""

from __future__ import annotations

import numpy as np
import pytest

from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.simulation import Simulation
from hpcmpm.solvers.semi_implicit import SolverFailure

# A neo-Hookean block ringing in its first axial mode (amplitude 0.01 m/s), carried at U.
BLOCK = """
[simulation]
dim = 2
domain = {{ lower = [-2.0, -2.0], upper = [2.0, 2.0] }}
dx = 0.05
particles_per_cell = 2
kernel = "quadratic"
transfer = "apic"
integrator = "semi_implicit"
end_time = 1.0
dt = 1e-3

[solver]
mode = "{mode}"
tolerance = 1e-6
preconditioner = "{preconditioner}"
newton_stop = "{newton_stop}"

[[materials]]
name = "m"
type = "neo_hookean"
density = 1000.0
E = {E}
nu = 0.3

[[bodies]]
name = "b"
material = "m"
shape = "box"
lower = [-0.5, -0.25]
upper = [0.5, 0.25]
velocity = [{U}, 0.0]
velocity_field = {{ type = "axial_mode", amplitude = 0.01, length = 1.0, axis = 0 }}
"""


def one_step(U, preconditioner, E=1e6, mode="linearized", newton_stop="momentum",
             steps=1):
    scene = parse_scene(BLOCK.format(U=U, preconditioner=preconditioner, E=E, mode=mode,
                                     newton_stop=newton_stop))
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    for _ in range(steps):
        sim.step(scene.dt)
    v = sim.particles["v"].copy()
    v[:, 0] -= U
    return v, sim.integrator.last_step["cg_iterations"]


@pytest.mark.parametrize("U", [3.0, 300.0])
@pytest.mark.parametrize("preconditioner", ["jacobi", "none"])
def test_a_uniform_velocity_does_not_change_the_solve(U, preconditioner):
    """Without a preconditioner the stop still needs H's diagonal (S), computed for it alone."""
    at_rest, iterations = one_step(0.0, preconditioner)
    carried, carried_iterations = one_step(U, preconditioner)
    assert iterations > 0
    assert carried_iterations == iterations
    # The same CG on the same b: what is left is round-off of v - U, eps U / |v| ~ 1e-11 at
    # U = 300 (measured 2.8e-11; 3.3e-13 at U = 3). 1e-9 is four orders below the 3.2e-4 the
    # old floor left at U = 3.
    scale = np.abs(at_rest).max()
    assert np.abs(carried - at_rest).max() <= 1e-9 * scale


@pytest.mark.parametrize("U", [3.0, 300.0])
def test_newton_with_the_galilean_stop_does_not_depend_on_a_uniform_velocity(U):
    """Newton's stop as the issue gives it, |grad E| <= newton_tolerance |M v*|, loosens
    with U like the old linear floor: measured on this block at newton_tolerance 1e-6, v - U
    off the run at rest by 1.2e-5 of its velocities at U = 3 and 3.3e-2 at U = 300, where
    Newton took no step. ``solver.newton_stop = "galilean"`` stops at |grad E| <=
    max(newton_tolerance |M (v* - c)|, 64 eps S |M v*|) instead
    (`SemiImplicitIntegrator._newton_reference`)."""
    at_rest, iterations = one_step(0.0, "jacobi", mode="newton", newton_stop="galilean")
    carried, carried_iterations = one_step(U, "jacobi", mode="newton", newton_stop="galilean")
    assert iterations > 0 and carried_iterations == iterations
    scale = np.abs(at_rest).max()
    # The same iterates up to round-off of v - U, eps U / |v| (measured 3.1e-13 at U = 3,
    # 3.3e-11 at U = 300), as for the linear stop above.
    assert np.abs(carried - at_rest).max() <= 1e-9 * scale
    if U == 300.0:  # the issue's stop, for contrast: the test can tell the two apart
        issue, _ = one_step(U, "jacobi", mode="newton", newton_stop="momentum")
        assert np.abs(issue - at_rest).max() > 1e-3 * scale


@pytest.mark.parametrize("mode, newton_stop", [("linearized", "momentum"),
                                               ("newton", "galilean")])
def test_a_stiff_body_in_free_flight_is_not_solved_to_round_off(mode, newton_stop):
    """pie_2d's first 0.07 s: the pie (a crust 1e5 times stiffer than its cream) flies at
    3 m/s before it nears the target, stress-free, at 2e5 times its explicit stiffness ratio
    (S = max diag(H)/m). Its b is round-off, up to 78 eps S |M v*| by t = 0.07 (measured);
    solving that to 1e-6 took 26 867 CG iterations in these 68 steps (up to 672 in one step)
    without the round-off stop, and 7 with it. Newton with the galilean stop has the same
    round-off term (measured: 2 Newton iterations, 4 CG iterations in the 68 steps)."""
    scene = load_scene("inputs/pie_2d.toml", [f'solver.mode="{mode}"',
                                              f'solver.newton_stop="{newton_stop}"'])
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    steps = total = 0
    while sim.time < 0.07:
        sim.step(min(sim.stable_dt(), 0.07 - sim.time))
        total += sim.integrator.last_step["cg_iterations"]
        steps += 1
    # 5 an iteration per step on average is far below the 395 a step without the stop.
    assert total <= 5 * steps
    # Still a flight: nothing has hit anything.
    v = sim.particles["v"]
    np.testing.assert_allclose(v[:, 0], 3.0, rtol=1e-6)


def test_a_stiffness_beyond_the_float_range_stops_the_solve():
    """E = 1e308: the round-off stop (64 eps S |M v*|, S ~ 1e299 here) squares beyond the
    float range. As inf it skipped every solve, and the step went on at v* as if the
    material had no stiffness (measured: toothpaste_3d with lambda = 1e308 ran to its end,
    the paste falling freely). Now the step stops with a SolverFailure (exit code 3)."""
    with pytest.raises(SolverFailure, match=r"stiffness is beyond the floating-point range"):
        one_step(3.0, "jacobi", E=1e308)

"""Coulomb friction on a separating floor decelerates a sliding body at mu * g.

Reference: a rigid block sliding on a floor with Coulomb friction mu under gravity g has
tangential speed v_t(t) = v0 - mu g t until it stops (and then stays stopped), whatever its
mass. In MPM the floor acts on the grid (Stomakhin 2013 §8, `hpcmpm.boundaries.contact`):
each step gravity gives a floor node v_n = -g dt, the separate condition removes it and takes
mu |v_n| = mu g dt off the tangential speed.
"""

import types

import numpy as np
import pytest

from hpcmpm.boundaries import Collider, Walls

MU, G, V0, DT, STEPS = 0.3, 9.81, 2.0, 1e-3, 1000


def slide(apply, dim, direction):
    """One floor node, the grid update (gravity) then the boundary, STEPS times."""
    v = np.zeros((1,) * dim + (dim,))
    v[(0,) * dim][: dim - 1] = V0 * direction
    history = []
    for n in range(STEPS):
        v[(0,) * dim][dim - 1] -= G * DT  # gravity pushes into the floor
        apply(v, n * DT)
        history.append(v[(0,) * dim].copy())
    return np.array(history)


def floor_walls(dim):
    faces = [types.SimpleNamespace(condition="slip", friction=0.0)] * (2 * dim)
    faces[2 * (dim - 1)] = types.SimpleNamespace(condition="separate", friction=MU)
    return Walls(faces, [10] * dim)


def floor_collider(dim):
    spec = types.SimpleNamespace(name="floor", shape="half_space", condition="separate",
                                 friction=MU, velocity=(), angular_velocity=None, start=0.0,
                                 end=np.inf, params={"point": [0.0] * dim,
                                                     "normal": [0.0] * (dim - 1) + [1.0]})
    return Collider(spec, dim)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("obstacle", ["wall", "collider"])
def test_floor_node_decelerates_at_mu_g_exactly(dim, obstacle):
    """Kernel level: the projection gives v_t(t_n) = max(v0 - mu g t_n, 0) to round-off
    (it is the same arithmetic as the formula, so 1e-12 over 1000 steps), the normal velocity
    stays zero, and in 3D the tangential direction never turns."""
    direction = np.array([1.0]) if dim == 2 else np.array([0.6, 0.8])
    origin = np.array([5] * (dim - 1) + [0])  # a node on the floor (global index 0)
    if obstacle == "wall":
        boundary = floor_walls(dim)
    else:
        boundary = floor_collider(dim)
    mass = np.ones((1,) * dim)
    history = slide(lambda v, t: boundary.apply(v, origin, 0.1, np.zeros(dim), t, DT, mass),
                    dim, direction)
    t = DT * np.arange(1, STEPS + 1)
    expected = np.maximum(V0 - MU * G * t, 0.0)
    assert expected[-1] == 0.0 and expected[STEPS // 2] > 0  # it slides, then stops
    np.testing.assert_allclose(history[:, : dim - 1], expected[:, None] * direction, rtol=0,
                               atol=1e-12)
    assert np.all(history[:, dim - 1] == 0.0)


SEMI_IMPLICIT = """
integrator = "semi_implicit"
[solver]
mode = "{mode}"
"""


@pytest.mark.parametrize("integrator, cfl", [("explicit", 0.4), ("newton", 0.4),
                                             ("newton", 0.1), ("linearized", 0.4),
                                             ("linearized", 0.1)])
def test_elastic_block_sliding_on_a_floor_decelerates_at_mu_g(tmp_path, integrator, cfl):
    """Full engine: a stiff Neo-Hookean block (0.2 x 0.1 m) launched at 2 m/s along a
    separating floor with mu = 0.3, g = 10. Its centre-of-mass velocity, fitted over
    0.1 s < t < 0.5 s (it is still sliding), decelerates at mu g = 3 m/s^2 within 2%: the
    normal impulse the floor nodes take per step averages M g dt, the elastic wobble of the
    block (a few percent of v) averages out in the fit. Measured: explicit 3.0106 (0.35%).

    Semi-implicit (dt from the advection bound: about 6x the explicit one at cfl 0.4): the
    floor's normal impulse is the reaction of the solve's constraint, and friction takes
    mu times it off the tangential speed (`SemiImplicitIntegrator._release_reactions`).
    Before that the friction acted on v* only, which the solve then overwrote: measured
    slope -0.0001 (linearized) and 0.0000 (Newton), the block slid on at 2 m/s. Measured
    with it (cfl 0.4 / 0.2 / 0.1 / 0.05): Newton 3.0005 / 3.0015 / 3.0046 / 3.0092,
    linearized 3.0135 / 3.0015 / 3.0047 / 3.0092. The linearized mode at cfl 0.4 gave 3.176
    before its step was also halved where it would raise the energy (`_admissible_step`)."""
    from hpcmpm.runner import simulate
    from hpcmpm.scene import load_scene

    path = tmp_path / "slide.toml"
    extra = "" if integrator == "explicit" else SEMI_IMPLICIT.format(mode=integrator)
    extra = f"cfl = {cfl}\n" + extra
    path.write_text("""
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [2.0, 0.5] }
dx = 0.02
particles_per_cell = 2
kernel = "quadratic"
transfer = "apic"
end_time = 0.5
gravity = [0.0, -10.0]
EXTRA

[output]
every = 0.1

[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1000.0
E = 1.0e5
nu = 0.3

[[bodies]]
name = "block"
material = "rubber"
shape = "box"
lower = [0.2, 0.0]
upper = [0.4, 0.1]
velocity = [2.0, 0.0]

[walls]
default = "slip"
y_lower = { condition = "separate", friction = 0.3 }
""".replace("EXTRA", extra))
    history = []

    def observe(sim):
        p = sim.particles
        history.append((sim.time, (p["mass"] * p["v"][:, 0]).sum() / p["mass"].sum()))

    simulate(load_scene(path), observer=observe)
    t, vx = np.array(history).T
    window = t > 0.1
    slope, _ = np.polyfit(t[window], vx[window], 1)
    assert abs(-slope - 3.0) < 0.02 * 3.0, slope
    assert abs(vx[-1] - (2.0 - 3.0 * t[-1])) < 0.05  # the speed itself, up to the wobble


IMPACT = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [1.0, 1.0] }
dx = 0.02
particles_per_cell = 2
kernel = "quadratic"
transfer = "apic"
cfl = CFL
end_time = 0.12
gravity = [0.0, 0.0]
EXTRA
[output]
every = 0.12

[[materials]]
name = "soft"
type = "neo_hookean"
density = 1000.0
E = 2.0e5
nu = 0.3

[[bodies]]
name = "block"
material = "soft"
shape = "box"
lower = [0.7, 0.4]
upper = [0.9, 0.6]
velocity = [3.0, -2.0]

[walls]
default = "slip"
x_upper = { condition = "separate", friction = 0.3 }
"""


def impact_impulses(tmp_path, cfl, mode):
    """(normal, friction) impulse per unit mass that the wall gave the block: its x momentum
    lost and its y momentum gained (no gravity, so nothing else changes them). ``mode``:
    None (explicit) or a semi-implicit solver mode."""
    from hpcmpm.runner import simulate
    from hpcmpm.scene import load_scene

    extra = SEMI_IMPLICIT.format(mode=mode) if mode else ""
    path = tmp_path / f"impact_{cfl}_{mode}.toml"
    path.write_text(IMPACT.replace("CFL", str(cfl)).replace("EXTRA", extra))
    final = {}

    def observe(sim):
        p = sim.particles
        final["p"] = (p["mass"][:, None] * p["v"]).sum(axis=0) / p["mass"].sum()

    simulate(load_scene(path), observer=observe)
    vx, vy = final["p"]
    return 3.0 - vx, vy + 2.0


def test_frictional_impact_semi_implicit_converges_to_the_explicit_impulses(tmp_path):
    """A soft block (E = 2e5, 0.2 m) thrown at 3 m/s against a separating wall with mu = 0.3
    while sliding along it at 2 m/s: it bounces, and friction takes y momentum during the
    contact. The semi-implicit step's impulses converge to the explicit ones as dt falls
    (measured, per unit mass: explicit at cfl 0.1 normal 5.657, friction 1.238; linearized
    at cfl 0.4 / 0.1 / 0.025 friction 0.809 / 1.274 / 1.239, normal 4.793 / 5.574 / 5.631).
    Bar: at cfl 0.025 within 1 % of the explicit impulses (0.1 % and 0.5 % measured), and
    the friction error smaller than at cfl 0.1. With friction acting on v* only (the defect
    `_release_reactions` fixed) the friction impulse at cfl 0.025 was 0.546, under half."""
    normal_e, friction_e = impact_impulses(tmp_path, 0.1, None)
    normal_coarse, friction_coarse = impact_impulses(tmp_path, 0.1, "linearized")
    normal_fine, friction_fine = impact_impulses(tmp_path, 0.025, "linearized")
    assert friction_e > 1.0  # friction worked against 2 m/s of sliding
    assert abs(friction_fine - friction_e) < 0.01 * friction_e, (friction_fine, friction_e)
    assert abs(normal_fine - normal_e) < 0.01 * normal_e, (normal_fine, normal_e)
    assert abs(friction_fine - friction_e) < abs(friction_coarse - friction_e)


def test_newton_completes_the_impact_at_a_large_step(tmp_path):
    """The same impact in Newton mode at cfl 0.4 (48 steps; the CG meets negative curvature
    and the tangents are convexified). Newton used to give up after 50 iterations at step
    18 (|grad E| 10.1 against 8.3e-6): its line search started every step at alpha =
    dx / (dt max_i |dv_i|), and the direction held hundreds of m/s at nodes of negligible
    mass (at dx = 0.01: 635 m/s at 2e-9 kg, median 0.25 m/s), so each step went about 1 %
    of the way. With the mass-weighted start it converges; the impulses then lie with the
    linearized mode's at that step (measured normal 4.877, friction 0.904; linearized 4.793,
    0.809), short of the converged 5.63 / 1.24 as a contact resolved by a few steps is."""
    normal, friction = impact_impulses(tmp_path, 0.4, "newton")
    assert 4.0 < normal < 6.0 and 0.5 < friction < 1.3, (normal, friction)

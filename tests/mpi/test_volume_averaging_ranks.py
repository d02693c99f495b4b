"""``simulation.volume_averaging = "increment"`` (hpcmpm/kernels/volume.py): the engine's average
of the step's change of J through the distributed grid equals a one-process average written
here from the B-spline formula, on 1, 2 and 4 ranks, in 2D and 3D, on a periodic axis too; it
conserves the total volume sum_p V0_p J_p, keeps a uniform ratio and a state at rest, keeps a
linear J inside a regular lattice, and leaves a non-finite J and other materials alone."""

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation
from volume_reference import reference_average
from mpi_helpers import gather_by_id

MATERIAL = """
[[materials]]
name = "paste"
type = "herschel_bulkley"
density = 2.0
mu = 50.0
lambda = 500.0
yield_strain = 0.1
flow_index = 1.0
flow_consistency = 1.0

[[materials]]
name = "rubber"
type = "neo_hookean"
density = 1.0
E = 1.0e4
nu = 0.3

[[materials]]
name = "water"
type = "weakly_compressible"
density = 10.0
E = 1.0e4
"""


def scene_text(dim: int, kernel: str, periodic: bool) -> str:
    hi = ", ".join(["1.0"] * dim)
    lower = ", ".join(["0.2"] * dim)
    upper = ", ".join(["0.8"] + ["0.5"] * (dim - 1))
    # A body of a material whose J is not averaged (neo-Hookean carries F) overlaps the
    # paste's upper part: its particles must neither contribute nor change. A water body
    # five times as dense as the paste shares the nodes below it: both are averaged
    # together, weighed by volume (V0 J), not by mass.
    lower2 = ", ".join(["0.2"] + ["0.4"] * (dim - 1))
    upper2 = ", ".join(["0.8"] + ["0.7"] * (dim - 1))
    return f"""
[simulation]
dim = {dim}
domain = {{ lower = [{", ".join(["0.0"] * dim)}], upper = [{hi}] }}
dx = {0.0625 if dim == 2 else 0.125}
particles_per_cell = 2
kernel = "{kernel}"
end_time = 1.0
volume_averaging = "increment"
{'periodic = ["x"]' if periodic else ''}
{MATERIAL}
[[bodies]]
name = "paste"
material = "paste"
shape = "box"
lower = [{"0.0" if periodic else "0.2"}, {", ".join(lower.split(", ")[1:])}]
upper = [{"1.0" if periodic else "0.8"}, {", ".join(upper.split(", ")[1:])}]
jitter = 0.4

[[bodies]]
name = "rubber"
material = "rubber"
shape = "box"
lower = [{lower2}]
upper = [{upper2}]

[[bodies]]
name = "water"
material = "water"
shape = "box"
lower = [{", ".join(["0.2", "0.05"] + ["0.2"] * (dim - 2))}]
upper = [{", ".join(["0.8", "0.2"] + ["0.5"] * (dim - 2))}]
jitter = 0.4
"""


def averaged(sim, J_new) -> dict:
    """One average as the step runs it: x^n, J^n kept, J^{n+1} = J_new(particles) set as the
    state update would, then the average; every rank's particles by id."""
    p = sim.particles
    sim.sort_phase()
    sim.fit_grid()
    sim.remember_volumes()
    p["J"][:] = J_new(p)
    sim.average_volumes()
    return gather_by_id(sim.domain, p)


def check(dim: int, kernel: str, periodic: bool) -> None:
    scene = parse_scene(scene_text(dim, kernel, periodic), path=f"average_{dim}d.toml")
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    p = sim.particles
    # J^n and J^{n+1} that vary by particle (by id: the same on every rank count).
    p["J"][:] = 1.0 + 0.3 * np.sin(0.7 * p["id"] + 0.1 * p["id"] ** 1.5)
    before = gather_by_id(sim.domain, p)
    change = lambda q: q["J"] * (1.0 + 0.2 * np.cos(1.3 * q["id"]))  # noqa: E731
    after = averaged(sim, change)
    paste = before["group"] != 1  # the paste and the water; the rubber is group 1
    assert (before["group"] == 0).sum() > 100 and (before["group"] == 2).sum() > 50
    assert (~paste).sum() > 50
    # The rubber keeps its own new J, to the bit.
    assert np.array_equal(after["J"][~paste], change(before)[~paste])
    order = 2 if kernel == "quadratic" else 3
    cells = int(round(1.0 / sim.dx)) if periodic else 0
    J_new = change(before)[paste]
    expected = reference_average(before["x"][paste], before["vol0"][paste],
                                 before["J"][paste], J_new, sim.dx, order, cells)
    # Sums of <= 64 positive terms per node and per particle, in another order: round-off.
    np.testing.assert_allclose(after["J"][paste], expected, rtol=1e-13, atol=0)
    # Not the identity: the average moves J by a sizeable fraction of the 0.2 change.
    assert np.abs(after["J"][paste] - J_new).max() > 0.05
    # Total volume: sum_p V0_p J_p^{n+1} is conserved (partition of unity), to round-off.
    V0 = before["vol0"][paste]
    assert np.sum(V0 * after["J"][paste]) == pytest.approx(np.sum(V0 * J_new), rel=1e-13)
    # Weighed by mass instead, the dense water would pull the shared nodes: not what ran.
    by_mass = reference_average(before["x"][paste], before["mass"][paste], before["J"][paste],
                                J_new, sim.dx, order, cells)
    assert np.abs(by_mass - expected).max() > 1e-3
    # A uniform ratio is kept (every r_i is 1.25), and so is a state at rest.
    start = gather_by_id(sim.domain, p)["J"]
    again = averaged(sim, lambda q: 1.25 * q["J"])
    np.testing.assert_allclose(again["J"], 1.25 * start, rtol=1e-14, atol=0)
    still = averaged(sim, lambda q: q["J"])
    np.testing.assert_allclose(still["J"], again["J"], rtol=1e-14, atol=0)
    # A particle whose new J is not finite neither spreads nor changes.
    bad = int(before["id"][paste][len(J_new) // 2])
    broken = averaged(sim, lambda q: np.where(q["id"] == bad, np.nan, q["J"]))
    assert np.isnan(broken["J"][broken["id"] == bad]).all()
    assert np.isfinite(np.delete(broken["J"], np.flatnonzero(broken["id"] == bad))).all()


def check_linear_field(dim: int, kernel: str) -> None:
    """From J^n = 1, a new J linear in x on a regular lattice (no jitter) is kept exactly
    away from the body's faces: the nodal volume-weighted average of a linear field is its
    value at the particles' centroid about the node, which is the node where the lattice is
    symmetric about it, and the B-splines reproduce linear fields (linear completeness)."""
    dx = 1.0 / 16
    zeros, ones = ", ".join(["0.0"] * dim), ", ".join(["1.0"] * dim)
    text = f"""
[simulation]
dim = {dim}
domain = {{ lower = [{zeros}], upper = [{ones}] }}
dx = {dx}
particles_per_cell = 2
kernel = "{kernel}"
end_time = 1.0
volume_averaging = "increment"
{MATERIAL}
[[bodies]]
name = "paste"
material = "paste"
shape = "box"
lower = [{", ".join(["0.125"] * dim)}]
upper = [{", ".join(["0.875"] * dim)}]
"""
    scene = parse_scene(text, path=f"linear_{dim}d.toml")
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    p = sim.particles
    gradient = np.array([0.1, -0.05, 0.03][:dim])
    p["J"][:] = 1.0
    after = averaged(sim, lambda q: 1.0 + q["x"] @ gradient)
    x = after["x"]
    # Exact where every node of the particle's stencil has a symmetric lattice about it:
    # 1.5 + 1.5 cells from the faces (quadratic), 2 + 2 (cubic).
    reach = (3.0 if kernel == "quadratic" else 4.0) * dx
    inside = np.all((x > 0.125 + reach) & (x < 0.875 - reach), axis=1)
    assert inside.sum() >= 8 ** dim
    # Round-off of sums of O(1) terms.
    np.testing.assert_allclose(after["J"][inside], 1.0 + x[inside] @ gradient, rtol=0,
                               atol=1e-14)
    # Not vacuous: at the faces the one-sided average moves J.
    assert np.abs(after["J"][~inside] - 1.0 - x[~inside] @ gradient).max() > 1e-4


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_grid_average_of_J_equals_one_process_reference():
    # All cases in one launch: an mpiexec start costs more than the checks.
    for dim, kernel, periodic in ((2, "quadratic", False), (2, "cubic", True),
                                  (3, "quadratic", True), (3, "cubic", False)):
        check(dim, kernel, periodic)
    for dim, kernel in ((2, "quadratic"), (3, "cubic")):
        check_linear_field(dim, kernel)

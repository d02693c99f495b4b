"""``simulation.volume_averaging = "grid"`` (hpcmpm/kernels/volume.py): the engine's average
through the distributed grid equals a one-process average written here from the B-spline
formula, on 1, 2 and 4 ranks, in 2D and 3D, on a periodic axis too; it conserves the total
volume sum_p m_p J_p and keeps a uniform J."""

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation
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
"""


def scene_text(dim: int, kernel: str, periodic: bool) -> str:
    hi = ", ".join(["1.0"] * dim)
    lower = ", ".join(["0.2"] * dim)
    upper = ", ".join(["0.8"] + ["0.5"] * (dim - 1))
    # A second body of a material whose J is not averaged (neo-Hookean carries F) overlaps
    # the paste's upper part: its particles must neither contribute nor change.
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
volume_averaging = "grid"
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
"""


def weights_1d(xi: np.ndarray, order: int):
    """(base, w (n, order + 1)): the B-spline weights, written independently of the kernels."""
    if order == 2:
        base = np.floor(xi - 0.5).astype(np.int64)
        r = xi[:, None] - (base[:, None] + np.arange(3))
        a = np.abs(r)
        w = np.where(a < 0.5, 0.75 - a * a, 0.5 * (1.5 - a) ** 2)
    else:
        base = np.floor(xi).astype(np.int64) - 1
        a = np.abs(xi[:, None] - (base[:, None] + np.arange(4)))
        w = np.where(a < 1.0, 0.5 * a ** 3 - a * a + 2.0 / 3.0, (2.0 - a) ** 3 / 6.0)
    return base, w


def reference_average(x, mass, J, dx, order, dim, periodic_cells):
    """J_p <- sum_i w_ip (sum_q w_iq m_q J_q / sum_q w_iq m_q) over all particles at once;
    nodes along a periodic axis wrap modulo its cell count."""
    bases, ws = zip(*(weights_1d(x[:, a] / dx, order) for a in range(dim)))
    s = order + 1
    nodes, w = [], []
    for corner in np.ndindex(*(s,) * dim):
        idx = [bases[a] + corner[a] for a in range(dim)]
        if periodic_cells:
            idx[0] = idx[0] % periodic_cells
        nodes.append(np.stack(idx, axis=1))
        w.append(np.prod([ws[a][:, corner[a]] for a in range(dim)], axis=0))
    keys = np.concatenate(nodes)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(len(nodes), len(x))
    m = np.zeros(len(unique))
    mj = np.zeros(len(unique))
    for k in range(len(nodes)):
        np.add.at(m, inverse[k], w[k] * mass)
        np.add.at(mj, inverse[k], w[k] * mass * J)
    Ji = mj / m
    return sum(w[k] * Ji[inverse[k]] for k in range(len(nodes)))


def check(dim: int, kernel: str, periodic: bool) -> None:
    scene = parse_scene(scene_text(dim, kernel, periodic), path=f"average_{dim}d.toml")
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    p = sim.particles
    # A J that varies by particle (by id: the same on every rank count), 0.7 .. 1.3.
    p["J"][:] = 1.0 + 0.3 * np.sin(0.7 * p["id"] + 0.1 * p["id"] ** 1.5)
    before = gather_by_id(sim.domain, p)
    sim.sort_phase()
    sim.fit_grid()
    sim.average_volumes()
    after = gather_by_id(sim.domain, p)
    paste = before["group"] == 0
    assert paste.sum() > 100 and (~paste).sum() > 50
    # The other material is untouched, to the bit.
    assert np.array_equal(after["J"][~paste], before["J"][~paste])
    order = 2 if kernel == "quadratic" else 3
    cells = int(round(1.0 / sim.dx)) if periodic else 0
    expected = reference_average(before["x"][paste], before["mass"][paste],
                                 before["J"][paste], sim.dx, order, dim, cells)
    # Sums of <= 64 positive terms per node and per particle, in another order: round-off.
    np.testing.assert_allclose(after["J"][paste], expected, rtol=1e-13, atol=0)
    # Not the identity: the average moves J by a sizeable fraction of its 0.3 spread.
    assert np.abs(after["J"][paste] - before["J"][paste]).max() > 0.05
    # Total volume: sum_p m_p J_p is conserved (partition of unity), to round-off.
    m = before["mass"][paste]
    assert np.sum(m * after["J"][paste]) == pytest.approx(np.sum(m * before["J"][paste]),
                                                          rel=1e-13)
    # A uniform J is kept: every J_p is a convex combination of nodal averages of 1.25.
    p["J"][p["group"] == 0] = 1.25
    sim.fit_grid()
    sim.average_volumes()
    np.testing.assert_allclose(p["J"][p["group"] == 0], 1.25, rtol=1e-14, atol=0)


@pytest.mark.parallel(ranks=[1, 2, 4])
def test_grid_average_of_J_equals_one_process_reference():
    # All cases in one launch: an mpiexec start costs more than the checks.
    for dim, kernel, periodic in ((2, "quadratic", False), (2, "cubic", True),
                                  (3, "quadratic", True), (3, "cubic", False)):
        check(dim, kernel, periodic)

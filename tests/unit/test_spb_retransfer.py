"""SPB-MPM's "transfer again" (003 §6.3.1; hpcmpm/pd/spb.py, module docstring 4.) against its
definition, recomputed here with B-spline weights written independently of the kernels:

- the PD particles' momentum correction m_p dv_p is scattered from x^n_p = x_p - dt v_p
  and divided by the step's grid mass: dv_i = sum_p w_ip(x^n_p) m_p dv_p / m_i;
- every particle whose stencil (at its own x^n) holds a corrected node takes
  dC = D^-1 sum_i w_ip dv_i (x_i - x^n_p)^T; mode "F": F <- (I + dt C_new)(I + dt C_old)^-1 F,
  mode "L": the stored velocity gradient L takes the same dC (the state update follows).

The momentum tests (test_spb_coupled, test_spb_impact) cannot see where the correction is
scattered or how C and F take it: sum m v does not depend on either. Here MPM particles of a
plain material share the grid with an SPB body made PD at the first step, and each step's
dv gets a random part so that the correction is not small; no wall is in reach, so the
boundaries take nothing and no PD particle is held."""

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

ELASTIC = 'type = "fixed_corotated"\nE = 100.0\nnu = 0.3'
J2 = ('type = "j2"\nE = 100.0\nnu = 0.3\n'
      'hardening = { type = "johnson_cook", A = 4.0, B = 2.0 }')   # deformation mode "L"


def scene_text(dim, model, kernel, wall):
    """An SPB box and a plain MPM box side by side, sharing grid nodes; with ``wall`` both
    rest their lower y side one cell above a sticky floor, whose nodes take part of the
    correction."""
    lo, hi = ", ".join(["0.0"] * dim), ", ".join(["1.0"] * dim)
    y = 0.25 if wall else 0.0       # how far the boxes sit below the middle

    def corner(first, rest):
        return ", ".join([first, f"{rest - y:g}"] + [f"{rest:g}"] * (dim - 2))

    spin = "2.0" if dim == 2 else "[0.5, 2.0, -1.0]"
    walls = '[walls]\ny_lower = { condition = "sticky" }' if wall else ""
    return f"""
[simulation]
dim = {dim}
domain = {{ lower = [{lo}], upper = [{hi}] }}
dx = {0.05 if dim == 2 else 0.1}
kernel = "{kernel}"
transfer = "mls"
end_time = 0.1
[[materials]]
name = "pd"
density = 1.0
{model}
failure = {{ model = "spb", grid_energy = 1.0e6, bond_energy = 1.0e6 }}
[[materials]]
name = "mpm"
density = 2.0
{model}
[[bodies]]
material = "pd"
shape = "box"
lower = [{corner("0.3", 0.3)}]
upper = [{corner("0.5", 0.7)}]
velocity = [{", ".join(["0.3"] + ["-0.1"] * (dim - 1))}]
angular_velocity = {spin}
[[bodies]]
material = "mpm"
shape = "box"
lower = [{corner("0.52", 0.3)}]
upper = [{corner("0.7", 0.7)}]
velocity = [{", ".join(["-0.2"] + ["0.1"] * (dim - 1))}]
{walls}
"""


def bspline(r, kernel):
    """The 1D B-spline N(|r|) (quadratic or cubic) at grid-unit distance r."""
    r = np.abs(r)
    if kernel == "quadratic":
        return np.where(r < 0.5, 0.75 - r * r, np.where(r < 1.5, 0.5 * (1.5 - r) ** 2, 0.0))
    return np.where(r < 1.0, 0.5 * r ** 3 - r * r + 2.0 / 3.0,
                    np.where(r < 2.0, (2.0 - r) ** 3 / 6.0, 0.0))


def stencil(xn, sim, kernel):
    """For points xn (n, d): per stencil offset, the global node indices (n, d), weights
    (n,) and x_i - x (n, d). Every node with a nonzero weight is in the stencil (the support
    is 3 or 4 nodes wide)."""
    dx, lo = sim.dx, np.asarray(sim.domain_lo)
    xi = (xn - lo) / dx
    width = 3 if kernel == "quadratic" else 4
    base = np.floor(xi - 0.5).astype(np.int64) if width == 3 else np.floor(xi).astype(np.int64) - 1
    dim = xn.shape[1]
    for offset in np.ndindex(*[width] * dim):
        node = base + np.array(offset)
        w = np.prod(bspline(xi - node, kernel), axis=1)
        yield node, w, (lo + node * dx) - xn


def expected_grid_correction(sim, xn, mdv, kernel):
    """dv_i on the rank's block, from the momentum m_p dv_p scattered at xn."""
    grid = sim.grid
    shape = grid["mass"].shape
    mom = np.zeros(shape + (xn.shape[1],))
    for node, w, _ in stencil(xn, sim, kernel):
        local = tuple((node - np.asarray(grid.origin)).T)
        np.add.at(mom, local, w[:, None] * mdv)
    m = grid["mass"]
    return np.where(m[..., None] > 0.0, mom / np.where(m > 0.0, m, 1.0)[..., None], 0.0)


def expected_dC(sim, xn, dvel, kernel):
    """D^-1 sum_i w_ip dv_i (x_i - x^n_p)^T for every point, D^-1 = 4/dx^2 (quadratic) or
    3/dx^2 (cubic) by the B-splines' second moments."""
    grid = sim.grid
    dinv = (4.0 if kernel == "quadratic" else 3.0) / sim.dx ** 2
    out = np.zeros((len(xn), xn.shape[1], xn.shape[1]))
    for node, w, d in stencil(xn, sim, kernel):
        local = tuple((node - np.asarray(grid.origin)).T)
        out += dinv * w[:, None, None] * dvel[local][:, :, None] * d[:, None, :]
    return out


def expected_gather(sim, xn, field, kernel):
    """sum_i w_ip field_i for every point (weights at the points)."""
    grid = sim.grid
    out = np.zeros_like(xn)
    for node, w, _ in stencil(xn, sim, kernel):
        out += w[:, None] * field[tuple((node - np.asarray(grid.origin)).T)]
    return out


def stencil_holds(sim, xn, mask, kernel):
    """Whether a node of each point's stencil is in ``mask`` (the block's nodes)."""
    out = np.zeros(len(xn), bool)
    for node, _, _ in stencil(xn, sim, kernel):
        out |= mask[tuple((node - np.asarray(sim.grid.origin)).T)]
    return out


@pytest.mark.parametrize("dim,model,kernel,wall", [
    (2, ELASTIC, "quadratic", False), (2, ELASTIC, "cubic", False),
    (3, ELASTIC, "quadratic", False), (2, J2, "quadratic", False), (3, J2, "cubic", False),
    (2, ELASTIC, "quadratic", True), (3, J2, "cubic", True),
], ids=["2d-F-quadratic", "2d-F-cubic", "3d-F-quadratic", "2d-L-quadratic", "3d-L-cubic",
        "2d-F-quadratic-wall", "3d-L-cubic-wall"])
def test_retransfer_follows_its_definition(dim, model, kernel, wall):
    """Four steps, each re-transfer checked against the module docstring's sums: grid
    correction, C, and F (mode "F") or L (mode "L") of every particle, MPM and PD. With a
    sticky floor: the floor takes r_i from the corrected velocity; every particle gets
    sum_i w r_i (MPM particles and PD particles away from the floor: none of theirs), and a
    PD particle whose stencil holds such a node drops its own dv and takes the corrected
    grid velocity's increment sum_i w dv_i instead. Each expected value is a sum of at most
    64 products of the same inputs in another order, so the tolerance is 1e-12 of its
    largest entry (measured: grid 1.4e-14, C 5.3e-15)."""
    sc = parse_scene(scene_text(dim, model, kernel, wall), "<retransfer>")
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    ext = sim.extensions[0]
    ext.convert_all = True
    mode_l = sim.deformation == "L"
    assert mode_l == (model == J2)
    p = sim.particles
    rng = np.random.default_rng(7)
    original = ext._retransfer
    held, converted = [], []

    def checked_retransfer(sim, pd_rows, dv, dt):
        # A random part on top of the bond forces' dv (a few % of the speeds; kept
        # consistent with x = x^n + dt v, as _evolve leaves the PD particles).
        extra = 0.05 * rng.standard_normal(dv.shape)
        p["v"][pd_rows] += extra
        p["x"][pd_rows] += dt * extra
        dv = dv + extra
        xn = p["x"] - dt * p["v"]
        before = {k: p[k].copy() for k in ("x", "v", "C", "F", "L") if k in p.specs}
        original(sim, pd_rows, dv, dt)
        # The free correction: scattered at x^n, divided by the grid mass.
        free = expected_grid_correction(sim, xn[pd_rows], p["mass"][pd_rows][:, None] * dv,
                                        kernel)
        scale = np.abs(free).max()
        assert scale > 0.01
        taken = sim.grid["spb_dvelocity"]        # what the particles take, after the walls
        r = taken - free                          # what the walls took
        floor = np.abs(r).max(axis=-1) > 1e-12 * scale
        assert floor.any() == wall
        if not wall:
            assert np.abs(r).max() < 1e-12 * scale
        # PD particles held by the floor's nodes.
        is_held = np.zeros(p.n, bool)
        is_held[pd_rows] = stencil_holds(sim, xn[pd_rows], floor, kernel)
        assert ext.held == is_held.sum()
        shift = expected_gather(sim, xn, np.where(floor[..., None], r, 0.0), kernel)
        shift[pd_rows[is_held[pd_rows]]] = (
            expected_gather(sim, xn[is_held], taken, kernel) - dv[is_held[pd_rows]])
        vscale = np.abs(before["v"]).max()
        assert np.abs(p["v"] - (before["v"] + shift)).max() < 1e-12 * vscale
        assert np.abs(p["x"] - (before["x"] + dt * shift)).max() < 1e-12 * vscale
        if wall:
            moved = np.abs(shift).max(axis=1) > 1e-12 * vscale
            assert (moved & (p["model"] == 0)).any() and is_held.any()
        dC = expected_dC(sim, xn, taken, kernel)
        touched = np.abs(dC).max(axis=(1, 2)) > 0.0
        # Both materials' particles (MPM and PD) take the correction.
        assert touched[p["model"] == 0].any() and touched[p["model"] == 1].any()
        C_new = before["C"] + dC
        gscale = np.abs(dC).max()
        assert np.abs(p["C"] - C_new).max() < 1e-12 * gscale
        if mode_l:
            assert np.abs(p["L"] - (before["L"] + dC)).max() < 1e-12 * gscale
            assert "F" not in before or np.array_equal(p["F"], before["F"])
        else:
            eye = np.eye(dim)
            F_new = (eye + dt * C_new) @ np.linalg.solve(eye + dt * before["C"], before["F"])
            assert np.abs(p["F"] - F_new).max() < 1e-12 * dt * gscale
        held.append(ext.held)
        converted.append(len(pd_rows))

    ext._retransfer = checked_retransfer
    steps = 4
    for _ in range(steps):
        sim.step(sim.stable_dt())
    # Every step re-transfers; the SPB box turned PD at the first, the other box is MPM.
    assert len(held) == steps and converted == [np.sum(p["model"] == 1)] * steps
    assert 0 < converted[0] < p.n
    print(f"held PD particles per step: {held}")

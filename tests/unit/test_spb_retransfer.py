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


def scene_text(dim, model, kernel):
    lo, hi = ", ".join(["0.0"] * dim), ", ".join(["1.0"] * dim)
    a_lo, a_hi = ", ".join(["0.3"] * dim), ", ".join(["0.5"] + ["0.7"] * (dim - 1))
    b_lo, b_hi = ", ".join(["0.52"] + ["0.3"] * (dim - 1)), ", ".join(["0.7"] * dim)
    spin = "2.0" if dim == 2 else "[0.5, 2.0, -1.0]"
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
lower = [{a_lo}]
upper = [{a_hi}]
velocity = [{", ".join(["0.3"] + ["-0.1"] * (dim - 1))}]
angular_velocity = {spin}
[[bodies]]
material = "mpm"
shape = "box"
lower = [{b_lo}]
upper = [{b_hi}]
velocity = [{", ".join(["-0.2"] + ["0.1"] * (dim - 1))}]
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


@pytest.mark.parametrize("dim,model,kernel", [
    (2, ELASTIC, "quadratic"), (2, ELASTIC, "cubic"), (3, ELASTIC, "quadratic"),
    (2, J2, "quadratic"), (3, J2, "cubic"),
], ids=["2d-F-quadratic", "2d-F-cubic", "3d-F-quadratic", "2d-L-quadratic", "3d-L-cubic"])
def test_retransfer_follows_its_definition(dim, model, kernel):
    """Four steps, each re-transfer checked against the module docstring's sums: grid
    correction, C, and F (mode "F") or L (mode "L") of every particle, MPM and PD. Each
    expected value is a sum of at most 64 products of the same inputs in another order, so
    the tolerance is 1e-12 of its largest entry (measured: grid 1.4e-14, C 5.3e-15)."""
    sc = parse_scene(scene_text(dim, model, kernel), "<retransfer>")
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    ext = sim.extensions[0]
    ext.convert_all = True
    mode_l = sim.deformation == "L"
    assert mode_l == (model == J2)
    p = sim.particles
    rng = np.random.default_rng(7)
    original = ext._retransfer
    checked = []

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
        grid_dv = sim.grid["spb_dvelocity"]
        want = expected_grid_correction(sim, xn[pd_rows], p["mass"][pd_rows][:, None] * dv,
                                        kernel)
        scale = np.abs(want).max()
        assert scale > 0.01
        assert np.abs(grid_dv - want).max() < 1e-12 * scale
        assert ext.held == 0
        assert np.array_equal(p["x"], before["x"])
        assert np.array_equal(p["v"], before["v"])
        dC = expected_dC(sim, xn, grid_dv, kernel)
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
        checked.append(len(pd_rows))

    ext._retransfer = checked_retransfer
    steps = 4
    for _ in range(steps):
        sim.step(sim.stable_dt())
    # Every step re-transfers; every particle of the SPB body became PD at the first.
    assert len(checked) == steps and checked[0] == np.sum(p["model"] == 1)

"""A block of material inside the semi-implicit step, its grid velocity prescribed as v_i = L x_i
(the solve replaced by that field), against the homogeneous material-point driver
(`hpcmpm.materials.driver`) under the same L (issue 9, "Homogeneous driver").

B-splines reproduce linear fields (000 §3.2: sum_i x_i grad w_ip^T = I), so G2P stores
L_p = L for every particle (APIC: grad w; MLS: C) and each particle's state follows the driver's
single point: Oldroyd-B (ob_spd) under start-up shear and extension, Herschel-Bulkley in shear.
The only difference is the round-off of L_p (a sum of 9 or 27 products, ~1e-16 relative) over
the steps: 1e-12 relative on b and J leaves room for 40 steps of it and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from hpcmpm.materials import make_material
from hpcmpm.materials.driver import drive
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation

STEPS, DT = 40, 0.02

SCENE = """
[simulation]
dim = {dim}
domain = {{ lower = {lo}, upper = {hi} }}
dx = 0.1
particles_per_cell = 2
kernel = "quadratic"
transfer = "{transfer}"
integrator = "semi_implicit"
end_time = 1.0

[[materials]]
name = "m"
type = "{type}"
density = 1.0
{params}

[[bodies]]
name = "block"
material = "m"
shape = "box"
lower = {body_lo}
upper = {body_hi}
"""


@dataclass
class Spec:
    type: str
    params: dict
    density: float = 1.0
    name: str = "m"


def toml_params(params):
    return "\n".join(f"{k} = {v!r}" if isinstance(v, str) else f"{k} = {v}"
                     for k, v in params.items()).replace("'", '"')


def block_run(dim, transfer, type_, params, L):
    lo, hi = [-2.0] * dim, [2.0] * dim
    text = SCENE.format(dim=dim, lo=lo, hi=hi, transfer=transfer, type=type_,
                        params=toml_params(params), body_lo=[-0.2] * dim, body_hi=[0.2] * dim)
    scene = parse_scene(text)
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    integ = sim.integrator

    def prescribed_solve(sim, dt):
        grid = sim.grid
        nodes = np.meshgrid(*grid.node_positions(), indexing="ij")
        grid["velocity"][...] = np.einsum("ab,b...->...a", L, np.array(nodes))

    integ.solve = prescribed_solve
    for _ in range(STEPS):
        sim.step(DT)
    return sim


CASES = {
    "oldroyd_b shear": ("oldroyd_b", {"mu": 1.0, "lambda": 10.0, "viscosity": 0.1,
                                      "relaxation_time": 1.0}, "shear"),
    "oldroyd_b extension": ("oldroyd_b", {"mu": 1.0, "lambda": 10.0, "viscosity": 0.1,
                                          "relaxation_time": 1.0}, "extension"),
    "herschel_bulkley shear": ("herschel_bulkley", {"mu": 1.0, "lambda": 10.0,
                                                    "yield_strain": 0.01, "flow_index": 0.5,
                                                    "flow_consistency": 0.01}, "shear"),
}


def velocity_gradient(kind, dim):
    L = np.zeros((dim, dim))
    if kind == "shear":
        L[0, 1] = 1.0
    else:
        L[np.diag_indices(dim)] = (0.25, -0.125, 0.0625)[:dim]
    return L


@pytest.mark.parametrize("case, dim, transfer", [("oldroyd_b shear", 2, "apic"),
                                                  ("oldroyd_b extension", 3, "mls"),
                                                  ("herschel_bulkley shear", 2, "mls")])
def test_block_matches_the_homogeneous_driver(case, dim, transfer):
    type_, params, kind = CASES[case]
    L = velocity_gradient(kind, dim)
    sim = block_run(dim, transfer, type_, params, L)
    ref = drive(make_material(Spec(type_, params), dim), lambda t: L, DT, STEPS)
    p = sim.particles
    assert sim.step_index == STEPS and p.n > 0
    assert np.abs(p["L"] - L).max() < 1e-13 * np.abs(L).max()  # G2P stored L itself
    for name in ("b", "J"):
        expected = ref.fields[name][0]
        err = np.abs(p[name] - expected).max() / np.abs(expected).max()
        assert err < 1e-12, f"{name}: {err:.2e}"
    moved = np.abs(ref.fields["b"][0] - np.eye(dim)).max()
    assert moved > 1e-3  # the state did evolve (HB: up to its yield strain 0.01)

"""A collider across a periodic face (hpcmpm/boundaries/colliders.py, periodic images), and
a turning prescribed set crossing one (hpcmpm/boundaries/prescribed.py, nearest image).

A periodic axis has no preferred origin: a layer of material filling the period and flowing
past a sticky disk gives the same motion, shifted, wherever along the axis the disk sits.
With the disk on the face x = 0 half of it lies beyond the face and acts through its image
one period away. Measured: the layer's velocities after 0.05 s agree with those of the disk
at x = 0.5, shifted by half the period, to 5e-15 (m/s, flow at 1 m/s); before colliders had
periodic images they were 0.13 m/s apart (the half beyond the face did not act)."""

from pathlib import Path

import numpy as np

from hpcmpm.parallel import Communicator
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain, simulate
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation
from periodic_layer_scenes import disk_in_flow, turning_set

def flow_past(cx: float):
    """Velocities after 0.05 s by the particle's start position, shifted so that the disk
    sits at x = 0.5: {(x mod 1, y) rounded to 1e-9: v}."""
    scene = parse_scene(disk_in_flow(cx), "disk.toml")
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    start = {int(i): x.copy() for i, x in zip(sim.particles["id"], sim.particles["x"])}
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=0.05, quiet=True)).run()
    p = sim.particles
    out = {}
    for i, v in zip(p["id"], p["v"]):
        x = start[int(i)]
        out[(round(float(np.mod(x[0] - cx + 0.5, 1.0)), 9), round(float(x[1]), 9))] = v
    return out


def test_disk_across_a_periodic_face_acts_as_one_inside():
    inside, across = flow_past(0.5), flow_past(0.0)
    assert inside.keys() == across.keys()
    keys = sorted(inside)
    a = np.array([inside[k] for k in keys])
    b = np.array([across[k] for k in keys])
    # The disk stops the layer in front of it: the flow is far from uniform.
    assert np.abs(a[:, 0] - 1.0).max() > 0.5
    # Round-off of sums in another particle order (measured 5e-15 of the 1 m/s flow).
    assert np.abs(a - b).max() < 1e-12


PRESCRIBED = turning_set(0.4, 0.6)


def test_turning_prescribed_set_crosses_a_periodic_face_rigidly():
    """A prescribed set (the whole body) turning at 3 rad/s about its centre while it travels
    at 2 m/s along the periodic axis: at t = 0.1 it straddles the face x = 1 (centre at 1.0,
    half its particles wrapped to x < 0.1). It moves as the same set in a domain twice as
    long and not periodic, where it never meets a face (positions modulo the period).
    Before, the nodes of the wrapped particles turned about the centre a period away
    (omega P = 3 m/s off; measured 3.0 m/s; now 3.6e-15)."""
    runs = {}
    for periodic in (True, False):
        text = PRESCRIBED if periodic else PRESCRIBED.replace(
            'periodic = ["x"]\n', "").replace("upper = [1.0, 1.0] }", "upper = [2.0, 1.0] }")
        p = simulate(parse_scene(text, "turning.toml"), 0.1).particles
        order = np.argsort(p["id"])
        runs[periodic] = (p["x"][order], p["v"][order])
    (x, v), (x_wide, v_wide) = runs[True], runs[False]
    assert (x[:, 0] < 0.5).any() and (x[:, 0] > 0.5).any()             # across the face
    assert np.abs(v_wide[:, 1]).max() > 0.2                             # it turns
    err = np.abs(v - v_wide).max()
    print(f"periodic against wide: velocities {err:.3g} m/s")
    # Round-off of sums in another order (measured below 1e-14).
    assert err < 1e-12
    assert np.abs(np.mod(x_wide[:, 0], 1.0) - x[:, 0]).max() < 1e-12

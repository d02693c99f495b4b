"""Two elastic disks collide and separate (Sulsky, Chen & Schreyer 1994, §5.1).

MPM conserves linear momentum exactly: P2G, the grid update and G2P each preserve it up to
round-off, contact included (no contact algorithm: the disks share grid velocities). The
total energy is recorded every step; without dissipation by design it must stay bounded.
"""

import numpy as np
import pytest

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene


@pytest.mark.parametrize("transfer", ["mls", "apic", "flip", "pic"])
def test_disks_conserve_momentum_and_bound_energy(transfer):
    # 2.4 s: through the impact (contact from t ~ 0.9 s) and the rebound, before either disk
    # reaches a wall, where the walls would (correctly) exchange momentum with the disks.
    scene = load_scene("inputs/disks_2d.toml", ["simulation.end_time=2.4",
                                                f'simulation.transfer="{transfer}"'])
    history = []

    def observe(sim):
        d = sim.diagnostics()
        history.append((sim.time, *d["momentum"][:2], d["kinetic_energy"], d["elastic_energy"]))

    sim = simulate(scene, observer=observe)
    t, px, py, kinetic, elastic = np.array(history).T
    p = sim.particles
    scale = np.abs(p["mass"] * np.linalg.norm(p["v"], axis=1)).sum()
    # Initial momentum is exactly zero (opposite velocities). Round-off of ~2500 particles x
    # 500 steps stays many orders below 1e-10 of the momentum scale.
    assert np.max(np.abs(px)) < 1e-10 * scale
    assert np.max(np.abs(py)) < 1e-10 * scale
    energy = kinetic + elastic
    e0 = 0.5 * 1000 * 2 * np.pi * 0.2 ** 2 * 0.1 ** 2 * 2  # 1/2 m |v|^2 of both disks
    # The lattice discretises each disk's area within a few percent.
    assert abs(energy[0] - e0) / e0 < 0.03
    # Bounded: never gains energy (beyond round-off of the estimate), and the disks really
    # collided: elastic energy rose to a visible fraction of the total mid-impact.
    assert energy.max() <= energy[0] * (1 + 1e-3)
    assert elastic.max() > 0.1 * energy[0]
    # The disks bounce back: the final kinetic energy is a large part of the initial one
    # (PIC dissipates most, the others keep more).
    assert kinetic[-1] > (0.2 if transfer == "pic" else 0.5) * energy[0]
    print(f"{transfer}: energy retained {energy[-1] / energy[0]:.3f}, "
          f"max |P| / scale {max(np.abs(px).max(), np.abs(py).max()) / scale:.2e}")

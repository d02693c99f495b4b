"""The dam break of inputs/dam_break_2d.toml against the surge-front measurements of Martin &
Moyce (1952).

J. C. Martin and W. J. Moyce, "Part IV. An experimental study of the collapse of liquid columns
on a rigid horizontal plane", Phil. Trans. R. Soc. Lond. A 244 (882), 312-324 (1952), Fig. 3:
front position Z = z / a against T = t sqrt(2 g / a) for columns of width a and height 2a
(n^2 = 2), the geometry of the scene (a = 0.3 m, height 0.6 m). The points below are the
figure's data as digitised in PySPH (pysph/examples/db_exp_data.py, mm_data_1 for a = 1.125 in
and mm_data_2 for a = 2.25 in), up to Z = 4.5.

The model is inviscid, with frictionless (separating) walls, and its column is released at
once; the measured front is held back by the floor, by viscosity and by the gate being lifted.
So the model's front must not lag the measured one (3 %: the scatter of the digitised points;
the two columns' own points differ by a few percent), and how far it leads is not fixed by
theory: 20 % is the bound this test holds it to (measured: 5-19 % ahead, the most early on,
T < 2). Once the surge has formed (T in [1.5, 4]) its speed is bounded by Ritter's
shallow-water dam break, dZ/dT = 2 (front speed 2 sqrt(g h0), h0 = 2a), and compared with the
measured slope (within 15 %; measured 11 % faster).
"""

import numpy as np

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene

A, G = 0.3, 9.81
# (T, Z) from Martin & Moyce (1952), Fig. 3, n^2 = 2.
MM_A1125 = np.array([[0.849, 1.245], [1.212, 1.443], [1.602, 1.884], [2.283, 2.689],
                     [2.950, 3.728], [3.598, 4.528]])
MM_A2250 = np.array([[0.832, 1.217], [1.219, 1.474], [1.997, 2.292], [2.547, 2.995],
                     [3.345, 4.134], [4.034, 4.944]])


def test_surge_front_against_martin_and_moyce():
    # A floor twice as long (2.0 m, Z up to 6.7) so the front meets no wall before T = 4.3.
    scene = load_scene("inputs/dam_break_2d.toml", ["simulation.end_time=0.52",
                                                    "simulation.domain.upper=[2.0, 1.0]"])
    half_spacing = scene.dx / scene.particles_per_cell / 2
    history = []

    def observe(sim):
        # The fluid's edge: the foremost particle plus half a particle spacing (Z = 1 at t = 0).
        history.append((sim.time, sim.particles["x"][:, 0].max() + half_spacing))

    simulate(scene, observer=observe)
    t, front = np.array(history).T
    T, Z = t * np.sqrt(2 * G / A), front / A
    assert T[-1] > 4.2
    for data in (MM_A1125, MM_A2250):
        model = np.interp(data[:, 0], T, Z)
        lead = (model - data[:, 1]) / data[:, 1]
        print("model ahead of Martin & Moyce by", np.round(lead, 3))
        assert np.all(lead > -0.03), lead  # never behind (3 %: the digitised points' scatter)
        assert np.all(lead < 0.20), lead
    developed = (T > 1.5) & (T < 4.0)
    slope = np.polyfit(T[developed], Z[developed], 1)[0]
    measured = np.polyfit(MM_A2250[2:, 0], MM_A2250[2:, 1], 1)[0]  # 1.32
    print(f"front speed dZ/dT: model {slope:.3f}, measured {measured:.3f}, Ritter bound 2")
    assert slope < 2.0
    assert abs(slope - measured) / measured < 0.15  # measured: 11 % faster

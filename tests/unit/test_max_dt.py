"""simulation.max_dt caps the CFL step."""

from hpcmpm.runner import simulate
from hpcmpm.scene import load_scene


def test_max_dt_caps_the_time_step():
    free = simulate(load_scene("inputs/bar_2d.toml", ["simulation.end_time=0.2"]))
    capped = simulate(load_scene("inputs/bar_2d.toml",
                                 ["simulation.end_time=0.2", "simulation.max_dt=0.004"]))
    # The CFL step of this scene is about 0.02: 10 steps to 0.2 versus 50 with the cap.
    assert free.step_index <= 12
    assert capped.step_index == 50

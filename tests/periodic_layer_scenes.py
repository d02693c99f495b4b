"""Scenes of a soft layer in a unit box periodic along x, shared by the one-process
invariants (tests/verification/test_collider_periodic.py) and their rank equivalence
(tests/mpi/test_periodic_boundaries_ranks.py): a disk collider in a flowing layer, and a
prescribed set that turns while it travels across the face x = 1."""


def _header(end_time: float, max_dt: float | None) -> str:
    step = f"max_dt = {max_dt}\n" if max_dt is not None else ""
    return f"""
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, 1.0] }}
dx = 0.025
transfer = "mls"
end_time = {end_time}
{step}periodic = ["x"]
[[materials]]
name = "m"
type = "neo_hookean"
density = 1.0
E = 100.0
nu = 0.3
"""


def disk_in_flow(cx: float, max_dt: float | None = None) -> str:
    """A layer 0.2 < y < 0.8 filling the period, flowing at 1 m/s past a sticky disk centred
    at (cx, 0.5), to t = 0.05. The radius keeps every grid node off the disk's surface,
    where round-off of the node positions (0.6 - 0.5 against 0.1 - 0.0) would decide inside
    or outside differently."""
    return _header(0.05, max_dt) + f"""[[bodies]]
material = "m"
shape = "box"
lower = [0.0, 0.2]
upper = [1.0, 0.8]
velocity = [1.0, 0.0]
[[colliders]]
shape = "sphere"
center = [{cx}, 0.5]
radius = 0.1013
"""


def turning_set(y_lower: float, y_upper: float) -> str:
    """A body 0.7 < x < 0.9, y_lower < y < y_upper, all of it a prescribed set travelling
    at 2 m/s along x and turning at 3 rad/s, to t = 0.1 (its centre then on x = 1)."""
    box = f"lower = [0.7, {y_lower}], upper = [0.9, {y_upper}]"
    return _header(0.1, 2e-3) + f"""[[bodies]]
material = "m"
shape = "box"
lower = [0.7, {y_lower}]
upper = [0.9, {y_upper}]
[[prescribed]]
region = {{ {box} }}
velocity = [2.0, 0.0]
angular_velocity = 3.0
"""

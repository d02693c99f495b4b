"""Start-up memory: the estimate, the one-line refusal naming count, bytes per rank and the
memory available, and what `hpcmpm validate` / `hpcmpm run` print for a scene far too big
(particles_per_cell = 100 in 3D: 2.7e9 particles) instead of a MemoryError."""

import re
import subprocess
import sys
from pathlib import Path

from hpcmpm import startup
from hpcmpm.geometry import count_scene, estimate_count
from hpcmpm.scene import load_scene

BIG = ("inputs/jelly_cube_3d.toml", "--set", "simulation.particles_per_cell=100")


def hpcmpm(*args):
    exe = Path(sys.executable).with_name("hpcmpm")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=120)


def test_estimate_counts_boxes_exactly_and_spheres_by_volume():
    jelly = load_scene("inputs/jelly_cube_3d.toml")
    assert estimate_count(jelly) == (count_scene(jelly).total, True)
    disks = load_scene("inputs/disks_2d.toml")
    guess, exact = estimate_count(disks)
    assert not exact
    # Two disks of radius 0.2 at spacing 0.01: the lattice count is within the boundary
    # layer (a few percent) of the area over the spacing squared.
    assert abs(guess - count_scene(disks).total) < 0.03 * guess


def test_refusal_names_count_bytes_per_rank_and_available_memory():
    scene = load_scene(*BIG[:1], [BIG[2]])
    estimate = startup.estimate_memory(scene, 2_744_000_000, 4, True)
    # 4 ranks hold up to 1.2 x the mean before a rebalance (the busiest rank is sized).
    share = 2_744_000_000 / 4 * 1.2
    assert estimate.per_rank > share * estimate.bytes_per_particle
    line = startup.memory_problem(scene, estimate, 4, 64 * 2**30)
    assert "\n" not in line
    assert line.startswith("inputs/jelly_cube_3d.toml: simulation.particles_per_cell: ")
    assert "2,744,000,000 particles" in line and "per rank on 4 rank(s)" in line
    assert "64.0 GiB available for 4 rank(s)" in line
    needed = int(re.search(r"at least (\d+) ranks", line).group(1))
    # That many ranks' shares do fit in what one rank may have here.
    assert startup.estimate_memory(scene, 2_744_000_000, needed, True).per_rank * 4 \
        <= 64 * 2**30 * 1.2
    assert startup.memory_problem(scene, estimate, 4, 10**15) is None


def test_validate_and_run_report_a_scene_too_big_in_one_line():
    proc = hpcmpm("validate", *BIG)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "inputs/jelly_cube_3d.toml: ok (2744000000 particles, 1 material, dim 3)"
    assert "2,744,000,000 particles" in lines[1] and "available" in lines[1]
    proc = hpcmpm("run", *BIG, "--dry-run", "--out", "/nonexistent/never/written")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    errors = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
    assert len(errors) == 1 and "2,744,000,000 particles" in errors[0], proc.stderr


def test_validate_report_and_dry_run_of_a_small_scene(capsys):
    ok, memory = startup.validate_report(load_scene("inputs/disks_2d.toml")).splitlines()
    assert ok == "inputs/disks_2d.toml: ok (2528 particles, 1 material, dim 2)"
    assert memory.startswith("inputs/disks_2d.toml: memory estimate: 2,528 particles, ")
    assert "available here" in memory
    from hpcmpm.cli import main

    assert main(["run", "inputs/disks_2d.toml", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "dry run on 1 rank(s): 2,528 particles, per rank min 2,528 / max 2,528" in out
    assert "peak RSS per rank" in out


def test_semi_implicit_scratch_is_in_the_estimate():
    """The semi-implicit solve's per-particle arrays (L, G, dL, dG, the tangents, and the
    Jacobi K while it is built) count in the start-up estimate: what the integrator declares
    equals what it holds after a step (per particle of capacity, plus the transient K), and
    a semi-implicit scene's bytes per particle exceed the same scene's explicit ones by the
    spare factor times that."""
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.simulation import Simulation
    from hpcmpm.solvers import SemiImplicitIntegrator

    overrides = ["simulation.dx=0.05"]
    scene = load_scene("inputs/sponge_twist_ob_3d.toml", overrides)
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    sim.step(sim.stable_dt())
    integ, d = sim.integrator, sim.dim
    held = sum(a.nbytes for a in (integ._L, integ._G, integ._dL, integ._dG, integ._T))
    per_particle = held / sim.particles.capacity + 8 * d ** 3
    declared = SemiImplicitIntegrator.scratch_bytes_per_particle(d)
    assert per_particle == declared == 8 * (4 * 9 + 81 + 27)  # 3D: 1152 B
    explicit = load_scene("inputs/sponge_twist_ob_3d.toml",
                          overrides + ['simulation.integrator="explicit"'])
    difference = startup.particle_bytes(scene) - startup.particle_bytes(explicit)
    assert abs(difference - startup.SPARE_FACTOR * declared) <= 1  # int() rounding


def test_start_up_estimate_counts_the_copies_of_volume_averaging():
    """Volume averaging keeps x^n and J^n of every particle (8 (d + 1) B at the capacity): the
    estimate holds them, as the run allocates them, and nothing without the option."""
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.simulation import Simulation

    overrides = ["simulation.dx=0.03125"]
    scene = load_scene("inputs/hb_mixer_2d.toml", overrides)
    assert scene.volume_averaging == "increment"
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    sim.step(sim.stable_dt())
    held = sim._x_old.nbytes + sim._J_old.nbytes
    assert held == sim.particles.capacity * sim.volume_scratch_bytes_per_particle() == \
        sim.particles.capacity * 8 * 3  # 2D
    plain = load_scene("inputs/hb_mixer_2d.toml",
                       overrides + ['simulation.volume_averaging="none"'])
    difference = startup.particle_bytes(scene) - startup.particle_bytes(plain)
    assert abs(difference - startup.SPARE_FACTOR * 24) <= 1  # int() rounding

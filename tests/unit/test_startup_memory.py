"""Start-up memory: the estimate, the one-line refusal naming count, bytes per rank and the
memory available, and what `hpcmpm validate` / `hpcmpm run` print for a scene far too big
(particles_per_cell = 100 in 3D: 2.7e9 particles) instead of a MemoryError."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

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
    # The advice is the least rank count the same check accepts: `needed` ranks, 4 a node,
    # fit in 64 GiB a node; one fewer does not (followed, the advice is not refused again).
    assert startup.estimate_memory(scene, 2_744_000_000, needed, True).per_rank * 4 \
        <= 64 * 2**30
    assert startup.estimate_memory(scene, 2_744_000_000, needed - 1, True).per_rank * 4 \
        > 64 * 2**30
    assert startup.memory_problem(scene, estimate, 4, 10**15) is None


def test_validate_advice_counts_the_busiest_rank_of_the_advised_run():
    """`hpcmpm validate` estimates one rank; the ranks it advises hold up to the rebalance
    factor (1.2) above the mean, which a count scaled from one rank left out (it advised 41
    ranks a node where each then needed 26 GiB of 22 GiB)."""
    scene = load_scene(*BIG[:1], [BIG[2]])
    one = startup.estimate_memory(scene, 2_744_000_000, 1, True)
    available = 22 * 2**30
    line = startup.memory_problem(scene, one, 1, available)
    needed = int(re.search(r"at least (\d+) ranks", line).group(1))
    assert startup.estimate_memory(scene, 2_744_000_000, needed, True).per_rank <= available
    assert startup.estimate_memory(scene, 2_744_000_000, needed - 1, True).per_rank \
        > available
    # and the search is not the scaled count (which is about 1.2x too few)
    scaled = (one.per_rank - startup.BASE_BYTES) / (available - startup.BASE_BYTES)
    assert needed > 1.15 * scaled


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


def test_a_mesh_scene_too_big_is_refused_before_its_points_are_counted():
    """watermelon_3d (two surface meshes) at particles_per_cell = 1000: `hpcmpm run` counted
    the meshes' 3.4e12 bounding-lattice points before its memory check (a fuzz campaign
    found it still counting after 8 minutes). The shapes' estimate now includes the meshes
    (`mesh_inside_fraction`), so the run refuses at once; the subprocess's 120 s timeout is
    what would catch a count."""
    proc = hpcmpm("run", "inputs/watermelon_3d.toml", "--set",
                  "simulation.particles_per_cell=1000", "--dry-run", "--out",
                  "/nonexistent/never/written")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    errors = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
    assert len(errors) == 1 and "simulation.particles_per_cell" in errors[0], proc.stderr
    assert "the scene needs about" in errors[0]


def test_a_grid_block_spanning_a_periodic_axis_is_refused_in_one_line(tmp_path):
    """channel_bingham_2d with its periodic x 1e9 times longer, the fluid still at
    x < 0.125: the one block of a single rank spans the period (the fluid's support wraps to
    the far face), 8e9 nodes along x. It was priced at the fluid's box (258 MiB), and the
    first step raised a MemoryError traceback asking for 4.4 TiB. Now validate and run name
    the grid block."""
    periodic = ("inputs/channel_bingham_2d.toml", "--set",
                "simulation.domain.upper=[125000000.0, 1.0]")
    proc = hpcmpm("validate", *periodic)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    problem = proc.stdout.splitlines()[1]
    assert problem.startswith("inputs/channel_bingham_2d.toml: simulation.dx: the scene needs")
    assert "dense grid block" in problem and "periodic" in problem
    proc = hpcmpm("run", *periodic, "--out", str(tmp_path / "out"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    errors = [l for l in proc.stderr.splitlines() if l.startswith("hpcmpm: error:")]
    assert len(errors) == 1 and "dense grid block" in errors[0], proc.stderr
    assert not (tmp_path / "out").exists()  # refused before the folder is made


def test_a_refused_run_with_force_keeps_the_other_runs_output(tmp_path):
    """`--force` replaces another run's output only once this run can start: a run refused
    at start-up (here for memory) removed the frames, checkpoints and XDMF of the run it
    was to replace, and then wrote nothing."""
    out = tmp_path / "out"
    out.mkdir()
    theirs = ["frame_000000.h5", "ckpt_000000100.h5", "particles.xdmf"]
    for name in theirs:
        (out / name).write_text("")
    proc = hpcmpm("run", *BIG, "--out", str(out), "--force")
    assert proc.returncode == 2 and "2,744,000,000 particles" in proc.stderr, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(theirs)


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
    assert per_particle == declared == 8 * (4 * 9 + 45 + 27)  # 3D: 864 B (T packed: 45)
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


def fake_files(files):
    """An ``open`` that serves ``files`` (path -> text) and fails like a missing file."""
    import io

    def fake_open(path, *args, **kwargs):
        if str(path) not in files:
            raise FileNotFoundError(path)
        return io.StringIO(files[str(path)])
    return fake_open


def test_available_memory_is_the_least_of_the_node_and_the_batch_job(monkeypatch):
    """MemAvailable (kB) and, under a cgroup v2 limit, the limit less what the job already
    uses: the smaller one is what this rank can still get."""
    meminfo = "MemTotal: 33554432 kB\nMemAvailable: 16777216 kB\n"  # 16 GiB available
    files = {"/proc/meminfo": meminfo, "/sys/fs/cgroup/memory.max": f"{8 * 2**30}\n",
             "/sys/fs/cgroup/memory.current": f"{3 * 2**30}\n"}
    monkeypatch.setattr(startup, "open", fake_files(files), raising=False)
    assert startup.available_memory() == 5 * 2**30  # 8 GiB limit - 3 GiB in use
    files["/sys/fs/cgroup/memory.max"] = f"{64 * 2**30}\n"  # a limit above the node's room
    assert startup.available_memory() == 16 * 2**30
    files["/sys/fs/cgroup/memory.max"] = "max\n"  # no limit
    assert startup.available_memory() == 16 * 2**30
    monkeypatch.setattr(startup, "open", fake_files({}), raising=False)
    assert startup.available_memory() is None  # nothing readable: nothing is refused


class NodeOf:
    """The Communicator verbs `check_memory` uses, for `size` ranks of which `local` share
    this node, every node alike."""

    def __init__(self, size, local):
        self.size, self.local = size, local

    def ranks_on_node(self):
        return self.local

    def max(self, x):
        return x

    def allgather(self, obj):
        return [obj] * self.size


def test_check_memory_refuses_when_the_ranks_of_a_node_together_do_not_fit(monkeypatch):
    """One rank's estimate fits in the node's memory, four of them on that node do not: the
    refusal is about all the ranks sharing the node."""
    from hpcmpm.errors import SceneError

    scene = load_scene("inputs/disks_2d.toml")
    per_rank = startup.estimate_memory(scene, 2528, 4, True).per_rank
    monkeypatch.setattr(startup, "available_memory", lambda: int(2.5 * per_rank))
    startup.check_memory(scene, NodeOf(4, 1), 2528, True)  # one rank per node: fits
    with pytest.raises(SceneError, match=r"for 4 rank\(s\)"):
        startup.check_memory(scene, NodeOf(4, 4), 2528, True)


def test_every_process_counts_its_base_size():
    """Each rank costs BASE_BYTES (interpreter, libraries, kernels) before any particle: a
    2,528-particle scene on 8 ranks of one node needs more than 8 x 256 MiB, so 1 GiB is
    refused and 4 GiB is not."""
    scene = load_scene("inputs/disks_2d.toml")
    estimate = startup.estimate_memory(scene, 2528, 8, True)
    assert estimate.per_rank >= startup.BASE_BYTES + 2528 / 8 * estimate.bytes_per_particle
    assert "8 rank(s)" in startup.memory_problem(scene, estimate, 8, 2**30)
    assert startup.memory_problem(scene, estimate, 8, 4 * 2**30) is None


def test_bond_bytes_are_shared_by_the_ranks():
    """The peridynamic bonds live with their particles: on P ranks the busiest holds
    rebalance_threshold / P of them, as it does of the particles."""
    scene = load_scene("inputs/pd_plate_tear_2d.toml")
    one = startup.estimate_memory(scene, 1600, 1, True)
    four = startup.estimate_memory(scene, 1600, 4, True)
    assert one.side_per_rank > 0
    factor = scene.parallel.rebalance_threshold / 4
    assert abs(four.side_per_rank - one.side_per_rank * factor) <= 1  # int() rounding


@pytest.mark.parametrize("scene, sets", [
    ("inputs/sponge_twist_3d.toml", ["simulation.dx=0.05"]),   # a small 3D grid: margins
    ("inputs/jelly_cube_3d.toml", []),
    ("inputs/disks_2d.toml", []),                               # two disks apart
    ("inputs/sponge_twist_ob_3d.toml", ["simulation.dx=0.05"]),  # semi-implicit: CG vectors
    # The fluid (x < 0.125) at a periodic face of a channel 32 times longer: the block spans
    # the period (it was priced at the fluid's box, 340 480 B against the 3 975 000 B held).
    ("inputs/channel_bingham_2d.toml", ["simulation.domain.upper=[4.0, 1.0]"]),
])
def test_grid_estimate_holds_the_block_a_step_allocates(scene, sets):
    """The grid allowance of the estimate (`grid_bytes`) is at least the block one rank
    holds after its first step (every field the step declared), and not far above it. The
    old allowance, twice the cells the particles fill, was a quarter of sponge_twist's block
    at dx = 0.05 (372 600 B held): a small block is mostly ghost layers and reuse margin."""
    from hpcmpm.parallel import Communicator
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.simulation import Simulation

    sc = load_scene(scene, sets)
    sim = Simulation(sc, make_domain(sc, Communicator()))
    initial_particles(sim)
    sim.step(sim.stable_dt())
    held = sim.grid.nbytes()
    allowance = startup.grid_bytes(sc, sim.particles.n, 1)
    print(f"{scene}: block {held} B, allowance {allowance:.0f} B")
    # At most 4x: the allowance takes the bodies' bounding box with the whole reuse margin,
    # and room for optional fields these scenes do not declare (measured 1.3x-2.7x).
    assert held <= allowance <= 4 * held


def test_off_grid_peridynamic_bodies_alone_are_estimated_without_a_grid_block():
    """A scene whose bodies are all off-grid PD (integration = "pd") allocates no grid block
    (`Simulation.uses_grid`), and the estimate prices none: Kalthoff-Winkler's plate, and
    the jelly figure whose on-grid material is only its correspondence stress model. The
    integral-based MPM bar (integration = "grid") keeps its block in both."""
    from hpcmpm.parallel import Communicator
    from hpcmpm.runner import initial_particles, make_domain
    from hpcmpm.simulation import Simulation

    for scene, on_grid in (("inputs/kalthoff_winkler_2d.toml", False),
                           ("inputs/pd_jelly_stretch_3d.toml", False),
                           ("inputs/ibmpm_bar_2d.toml", True)):
        sc = load_scene(scene)
        sim = Simulation(sc, make_domain(sc, Communicator()))
        initial_particles(sim)
        sim.step(sim.stable_dt())
        allowance = startup.grid_bytes(sc, sim.particles.n, 1)
        assert sim.uses_grid is on_grid
        assert (sim.grid.nbytes() > 0) is on_grid, scene
        assert (allowance > 0) is on_grid, scene

"""Shared by the benchmark scripts: the benchmark scenes, hpcmpm set-up, timing and reporting.

Scenes (every code gets the same particles, time step and grid):

- ``a``    Taichi's mpm88 setting: 8192 particles uniformly at random in [0.2, 0.6]^2, v = (0, -1),
           128^2 grid, dt = 2e-4, rho = 1, V_p = (dx/2)^2, the J-based weakly compressible fluid
           with E = 400, gravity 9.8, walls 3 nodes thick ("separate": the velocity component
           into a wall is removed).
- ``a_fc`` the same particles and step with fixed corotated elasticity, E = 400, nu = 0.2 (the
           same P-wave speed as the fluid, ~21, so mpm88's dt stays stable: CFL 0.54).
- ``b``    a 3D cube [0.25, 0.75]^3 sampled at 2 particles per cell per axis on a 64^3 grid
           (64^3 = 262144 particles), fixed corotated E = 400, nu = 0.2, rho = 1,
           V_p = (dx/2)^3, dt = 2e-4 (CFL 0.27), gravity 9.8, mpm3d's walls.

Particles are handed to every code in cell order (row-major over the grid), the order hpcmpm's
counting sort produces, so neither code starts from a cache-hostile random order.

hpcmpm's domain is the part of the peer's grid inside its walls: the peer zeroes the inward
velocity on nodes ``i < 3`` and ``i > n_grid - 3``; hpcmpm's walls act on its nodes ``<= 0`` and
``>= n_cells``, so ``domain_lo = 2 dx`` and ``domain_hi = (n_grid - 2) dx``. The integer shift
keeps every B-spline weight identical.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench_results"
FLUID, COROTATED, SNOW = "weakly_compressible", "fixed_corotated", "snow"


@dataclass(frozen=True)
class BenchScene:
    key: str
    title: str
    dim: int
    n_grid: int
    dt: float
    material: str
    params: dict
    x0: np.ndarray = field(repr=False)
    v0: np.ndarray = field(repr=False)
    p_vol: float = 0.0
    rho: float = 1.0
    gravity: float = 9.8
    bound: int = 3

    @property
    def n(self) -> int:
        return len(self.x0)

    @property
    def dx(self) -> float:
        return 1.0 / self.n_grid

    @property
    def p_mass(self) -> float:
        return self.p_vol * self.rho


def cell_order(x: np.ndarray, n_grid: int) -> np.ndarray:
    """Permutation putting particles in row-major cell order."""
    cells = np.floor(x * n_grid).astype(np.int64)
    key = np.zeros(len(x), dtype=np.int64)
    for a in range(x.shape[1]):
        key = key * n_grid + cells[:, a]
    return np.argsort(key, kind="stable")


def make_scene(key: str, smoke: bool = False, material: str | None = None,
               n2d: int | None = None) -> BenchScene:
    """The benchmark scene ``key`` (a, a_fc, b); ``smoke`` shrinks it to a few thousand
    particles; ``material`` overrides the material (memory study: snow); ``n2d`` sets the
    number of 2D particles, the grid growing with it at mpm88's density (memory study)."""
    E = 400.0
    if key in ("a", "a_fc"):
        n, n_grid = (512, 32) if smoke else (8192, 128)
        if n2d is not None:
            n, n_grid = n2d, max(16, int(round(128 * math.sqrt(n2d / 8192))))
        rng = np.random.default_rng(20180803)  # mpm88 draws ti.random(); we draw once, fixed
        x0 = rng.random((n, 2)) * 0.4 + 0.2
        x0 = x0[cell_order(x0, n_grid)]
        v0 = np.tile([0.0, -1.0], (n, 1))
        mat = material or (FLUID if key == "a" else COROTATED)
        title = ("2D mpm88, weakly compressible" if mat == FLUID
                 else f"2D mpm88 particles, {mat}")
        return BenchScene(key, title, 2, n_grid, 2e-4, mat, material_params(mat, E),
                          x0, v0, p_vol=(0.5 / n_grid) ** 2)
    if key == "b":
        n_grid = 16 if smoke else 64
        per_axis = n_grid  # 2 per cell over half the box
        ax = 0.25 + (np.arange(per_axis) + 0.5) * (0.5 / per_axis)
        x0 = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
        x0 = np.ascontiguousarray(x0[cell_order(x0, n_grid)])
        v0 = np.zeros_like(x0)
        mat = material or COROTATED
        return BenchScene(key, f"3D cube, {mat}", 3, n_grid, 2e-4, mat,
                          material_params(mat, E), x0, v0, p_vol=(0.5 / n_grid) ** 3)
    raise ValueError(f"unknown scene {key!r} (a, a_fc, b)")


def material_params(material: str, E: float) -> dict:
    if material == FLUID:
        return {"E": E}
    if material == SNOW:  # Stomakhin 2013's snow (theta_c, theta_s, xi), E as the others
        return {"E": E, "nu": 0.2, "theta_c": 2.5e-2, "theta_s": 7.5e-3, "xi": 10.0}
    return {"E": E, "nu": 0.2}


# -- hpcmpm ------------------------------------------------------------------------------------
def hpcmpm_toml(s: BenchScene, end_time: float = 1.0) -> str:
    """A scene file for hpcmpm describing ``s``'s domain, material, step and walls. Its body is
    the particles' bounding box; `build_hpcmpm` replaces the sampled particles by ``s.x0``."""
    d = s.dim
    lo = [(s.bound - 1) * s.dx] * d
    hi = [(s.n_grid - s.bound + 1) * s.dx] * d
    g = [0.0] * d
    g[1] = -s.gravity
    box_lo = s.x0.min(axis=0).tolist()
    box_hi = s.x0.max(axis=0).tolist()
    params = "\n".join(f"{k} = {v!r}" for k, v in s.params.items())
    vec = lambda xs: "[" + ", ".join(repr(float(x)) for x in xs) + "]"  # noqa: E731
    return f"""
[simulation]
dim = {d}
domain = {{ lower = {vec(lo)}, upper = {vec(hi)} }}
dx = {s.dx!r}
particles_per_cell = 2
kernel = "quadratic"
transfer = "mls"
dt = {s.dt!r}
end_time = {end_time!r}
gravity = {vec(g)}

[[materials]]
name = "m"
type = "{s.material}"
density = {s.rho!r}
{params}

[[bodies]]
name = "body"
material = "m"
shape = "box"
lower = {vec(box_lo)}
upper = {vec(box_hi)}
velocity = {vec(s.v0[0])}

[walls]
default = "separate"
friction = 0.0
"""


def build_hpcmpm(s: BenchScene, comm=None, select: np.ndarray | None = None):
    """A `Simulation` holding exactly ``s``'s particles (each rank a strided share, then the
    decomposition moves them to their owners, as `hpcmpm.runner.initial_particles` does);
    ``select`` (indices) keeps only those particles (the co-run baseline's halves)."""
    from hpcmpm.runner import make_domain
    from hpcmpm.scene import parse_scene
    from hpcmpm.simulation import Simulation

    scene = parse_scene(hpcmpm_toml(s), path=f"<bench {s.key}>")
    domain = make_domain(scene, comm)
    sim = Simulation(scene, domain)
    ids = np.arange(s.n, dtype=np.int64)
    mine = np.flatnonzero(ids % domain.size == domain.rank)
    if select is not None:
        mine = np.intersect1d(mine, select)
    sim.particles.append_rows({
        "id": ids, "group": np.zeros(s.n, dtype=np.int32), "x": s.x0, "v": s.v0,
        "mass": np.full(s.n, s.p_mass), "vol0": np.full(s.n, s.p_vol)}, mine)
    del ids, mine  # the harness's own arrays are not part of the run's memory
    domain.decompose(sim.particles)
    return sim


# -- timing ------------------------------------------------------------------------------------
def timed(run_steps, steps: int) -> float:
    """Seconds for ``run_steps(steps)`` (which must return only when the work is done)."""
    start = time.perf_counter()
    run_steps(steps)
    return time.perf_counter() - start


def frame_output_ms(sim, frames: int = 3) -> float:
    """Least wall time (ms) of writing one frame of ``sim`` (x, v, F or J, mass, id,
    material; serial HDF5, one file per frame) into a temporary folder, as `hpcmpm run`
    writes them. The peer writes nothing, so this is reported beside the step, not in it."""
    import tempfile

    from hpcmpm.io.frames import FrameWriter

    best = math.inf
    with tempfile.TemporaryDirectory(prefix="hpcmpm-bench-") as folder:
        writer = FrameWriter(folder, sim.domain, sim.scene.text, sim.dim, [],
                             {"restart_chain": []}, mode="serial")
        for _ in range(frames):
            start = time.perf_counter()
            writer.write(sim.particles, sim.time, sim.step_index)
            best = min(best, time.perf_counter() - start)
    return 1e3 * best


def summarize(seconds: list[float], steps: int, n: int) -> dict:
    """ms/step and particle-steps/s, best and median over repetitions."""
    best, med = min(seconds), statistics.median(seconds)
    return {"reps": len(seconds), "steps_per_rep": steps, "particles": n,
            "ms_per_step_min": 1e3 * best / steps, "ms_per_step_median": 1e3 * med / steps,
            "particle_steps_per_s_best": n * steps / best,
            "particle_steps_per_s_median": n * steps / med,
            "seconds": seconds}


def phase_ms(timers, steps: int) -> dict:
    """hpcmpm's PhaseTimers as ms per step per phase."""
    return {k: 1e3 * v / steps for k, v in timers.seconds.items()}


def machine_info() -> dict:
    model = platform.processor() or "unknown"
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    import numba

    info = {"cpu": model, "cpu_flags": cpu_flags(), "cores": os.cpu_count(),
            "cores_usable": len(os.sched_getaffinity(0)), "python": platform.python_version(),
            "numpy": np.__version__, "numba": numba.__version__,
            "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
            "NUMBA_NUM_THREADS": os.environ.get("NUMBA_NUM_THREADS"),
            # Other work on the machine skews timings; the load average says how much there was.
            "loadavg_1_5_15min": list(os.getloadavg())}
    try:
        from importlib.metadata import version

        info["taichi"] = version("taichi")
    except ImportError:
        info["taichi"] = None
    except Exception:  # PackageNotFoundError: no bench extra
        info["taichi"] = None
    try:
        info["git"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                                     capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def cpu_flags() -> str:
    """The CPU's feature flags (/proc/cpuinfo), which decide the vector code numba and Taichi's
    LLVM emit: part of what a timing depends on."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


# -- separate launches ----------------------------------------------------------------------
# One launch's timings move with the host (other processes, which vCPU a thread lands on, the
# memory a process happens to get): 45 % for the peer between launches of the same command.
# So a ratio is reported as its range over several launches, each a separate process.
RATIO_PREFIXES = ("ratio_", "efficiency")


def launch_separately(script: Path, argv_per_launch: list[list[str]], name: str,
                      timeout: float = 3600) -> list[dict]:
    """Run ``script --in-process ARGV`` once per argument list, each in its own process
    writing ``name`` into a folder of its own; returns the launches' JSON documents in order."""
    import tempfile

    docs = []
    with tempfile.TemporaryDirectory(prefix="bench-launch-") as tmp:
        for i, argv in enumerate(argv_per_launch):
            out = Path(tmp) / str(i)
            cmd = [sys.executable, str(script), *argv, "--in-process", "--out", str(out)]
            print(f"launch {i + 1}/{len(argv_per_launch)}: {' '.join(cmd[1:])}", flush=True)
            proc = subprocess.run(cmd, timeout=timeout)
            if proc.returncode:
                raise RuntimeError(f"{script.name} launch {i + 1} failed ({proc.returncode})")
            docs.append(json.loads((out / name).read_text()))
    return docs


def merge_launches(docs: list[dict]) -> dict:
    """One document from several launches: per scene the first launch's record, every ratio
    ``r`` also as ``r_range`` (min, max) and ``r_launches`` (all values), and every launch's
    whole record under ``launches``."""
    by_scene: dict[str, list[dict]] = {}
    for doc in docs:
        for r in doc["results"]:
            by_scene.setdefault(r["scene"], []).append(r)
    results = []
    for scene, records in by_scene.items():
        merged = dict(records[0])
        for key, value in records[0].items():
            if key.startswith(RATIO_PREFIXES) and isinstance(value, (int, float)):
                values = [float(r[key]) for r in records]
                merged[f"{key}_launches"] = values
                merged[f"{key}_range"] = [min(values), max(values)]
        merged["launches"] = records
        results.append(merged)
    machines = [d["machine"] for d in docs]
    return {"machine": machines[-1], "machines": machines, "launch_count": len(docs),
            "results": results}


def add_launch_arguments(ap) -> None:
    """``--launches N`` and the internal ``--in-process`` of a script whose ratios are
    reported over separate launches."""
    ap.add_argument("--launches", type=int, default=3,
                    help="separate processes per scene, each holding that scene alone; every "
                         "ratio is reported as its range over them (default 3)")
    ap.add_argument("--in-process", action="store_true",
                    help="run the scenes in this process (what each launch does)")


def run_launches(script: Path, args, keys: list[str], name: str, passthrough: list[str]) -> dict:
    """The launches of ``script``: for launch 1..N, every scene in its own process (scenes
    interleaved, so a slow spell of the host spreads over them); merged."""
    if args.launches < 1:
        raise SystemExit("--launches must be >= 1")
    argv = [[*passthrough, "--scene", key] for _ in range(args.launches) for key in keys]
    return merge_launches(launch_separately(script, argv, name))


def range_text(r: dict, key: str) -> str:
    """``"lo-hi (n launches)"`` of a merged ratio, or the single value."""
    if f"{key}_range" in r:
        lo, hi = r[f"{key}_range"]
        return f"{lo:.2f}-{hi:.2f} ({len(r[f'{key}_launches'])} launches)"
    return f"{r[key]:.2f} (1 launch)"


def write_json(name: str, payload: dict, out_dir: Path | None = None) -> Path:
    out = Path(out_dir) if out_dir else RESULTS
    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    path.write_text(json.dumps(payload, indent=2, default=float) + "\n")
    return path


def print_table(headers: list[str], rows: list[list]) -> None:
    cells = [[str(h) for h in headers]] + [[fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    for k, r in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))
        if k == 0:
            print("  ".join("-" * w for w in widths))
    sys.stdout.flush()


def fmt(x) -> str:
    if isinstance(x, float):
        if x == 0 or 1e-2 <= abs(x) < 1e5:
            return f"{x:.3f}" if abs(x) < 100 else f"{x:.1f}"
        return f"{x:.3g}"
    return str(x)

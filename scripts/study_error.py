#!/usr/bin/env python
"""Error versus cost: resolution x transfer x kernel sweeps on two problems with exact answers.

(a) bar: axial vibration of an elastic bar (inputs/bar_2d.toml); error = relative error of the
    first-mode period measured from the centre-of-mass velocity, as in
    tests/verification/test_bar_vibration.py.
(b) mms: a large-deformation manufactured solution in 1D-like 2D (Kamojjala et al. 2015;
    Steffen et al. 2008): u(X, t) = A sin(2 pi X) sin(pi t) along x on a unit bar [0, 1]
    fixed at both ends (sticky walls), Neo-Hookean with nu = 0 (lam = 0), so under uniaxial
    strain F = diag(F11, 1) the first Piola stress is P11 = mu (F11 - 1/F11). The body force
    b = d2u/dt2 - (1/rho0) dP11/dX is evaluated at each particle's reference position X and
    applied through `Simulation.forcing`. Error = RMS displacement error at the end time,
    divided by A.

(peer) bar only: the same bar in Taichi's MLS-MPM (scripts/peer/mls_bar.py: the loops of the
    benchmark peer scripts/peer/mls_mpm.py with hpcmpm's linear elastic material, walls and
    time-step rule), CPU backend, float64, one thread, started from hpcmpm's sampled particles;
    its period error is computed by the same function, `bar_period_error`, from the same
    observable. Rows have transfer "taichi-mls", kernel "quadratic". Skipped, with the reason
    printed, when Taichi cannot be imported or started.

Each run is timed with perf_counter after a warm-up run that compiles every kernel (numba, and
Taichi's JIT for the peer); the time kept is the least of --repeat runs (3; 1 with --smoke).
The peer's runs alternate with repeated hpcmpm MLS/quadratic runs of the same bar, whose time
goes in the peer's row as hpcmpm_mls_wall_s. Orders are least-squares slopes of log(error)
against log(dx).

    python scripts/study_error.py                   # 25, 50, 100 cells
    python scripts/study_error.py --problems bar    # the bar only (hpcmpm and the peer)
    python scripts/study_error.py --smoke           # 10, 20 cells, short runs (seconds)
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hpcmpm.kernels.transfer import APIC  # noqa: E402
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain  # noqa: E402
from hpcmpm.scene import load_scene, parse_scene  # noqa: E402
from hpcmpm.simulation import Simulation  # noqa: E402

TRANSFERS = ("pic", "flip", "apic", "mls")
KERNELS = ("quadratic", "cubic")

# -- (a) bar ----------------------------------------------------------------------------------
BAR_L, BAR_PERIOD = 25.0, 10.0


def bar_scene(cells: int, transfer: str = "mls", kernel: str = "quadratic",
              end_time: float = 8.0):
    return load_scene(REPO / "inputs/bar_2d.toml",
                      [f"simulation.dx={BAR_L / cells}", f"simulation.end_time={end_time}",
                       f'simulation.transfer="{transfer}"', f'simulation.kernel="{kernel}"'])


def bar_period_error(t: np.ndarray, v: np.ndarray) -> float:
    """Relative error of the first-mode period from the centre-of-mass velocity history
    v(t) (one entry after every step): twice the time between its first two zero crossings
    (linear interpolation), against BAR_PERIOD. Used for hpcmpm and the peer alike."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    i = np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))[:2]
    if len(i) < 2:
        return math.nan
    zeros = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    period = 2 * (zeros[1] - zeros[0])
    return abs(period - BAR_PERIOD) / BAR_PERIOD


def run_bar(cells: int, transfer: str, kernel: str, end_time: float = 8.0,
            info: dict | None = None) -> float:
    scene = bar_scene(cells, transfer, kernel, end_time)
    history = []

    def observe(sim):
        p = sim.particles
        history.append((sim.time, (p["mass"] * p["v"][:, 0]).sum() / p["mass"].sum()))

    run_sim(scene, end_time, observe)
    t, v = np.array(history).T
    if info is not None:
        info["steps"] = len(t)
    return bar_period_error(t, v)


# -- (peer) the bar in Taichi's MLS-MPM -----------------------------------------------------------
PEER = "taichi-mls"  # the peer's rows: transfer "taichi-mls", kernel "quadratic"


def start_peer():
    """The peer's bar module with Taichi started (CPU, float64, one thread), or the reason
    why not as a string."""
    sys.path.insert(0, str(REPO / "scripts" / "peer"))
    try:
        import mls_bar
        import mls_mpm
    except ImportError as exc:
        return f"taichi not importable ({exc}); pip install -e '.[bench]'"
    try:
        mls_mpm.init(threads=1)  # one core, as hpcmpm's NUMBA_NUM_THREADS=1
    except Exception as exc:  # noqa: BLE001 - any failure to start Taichi skips the peer
        return f"taichi did not start ({type(exc).__name__}: {exc})"
    return mls_bar


def make_peer_bar(mls_bar, cells: int):
    """The bar of `bar_scene(cells)` in the peer: hpcmpm samples the particles (ids give the
    order), the peer gets their positions, velocities, mass and volume, the scene's domain,
    dx, walls, material and CFL number. Field set-up only; nothing is compiled yet."""
    scene = bar_scene(cells)
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    p = sim.particles
    order = np.argsort(p["id"])
    mass, vol0 = p["mass"][order], p["vol0"][order]
    if np.ptp(mass) or np.ptp(vol0):
        raise ValueError("the peer takes one particle mass and volume")
    (mat,) = scene.materials
    if mat.type != "linear_elastic" or any(scene.gravity) or scene.dt is not None:
        raise ValueError("the peer bar is linear elastic, without gravity, at the CFL step")
    bar = mls_bar.MLSBar(scene.domain_lo, scene.domain_hi, scene.dx, p["x"][order],
                         p["v"][order], float(mass[0]), float(vol0[0]), mat.density,
                         float(mat.params["E"]), float(mat.params["nu"]),
                         walls=[f.condition for f in scene.walls.faces], cfl=scene.cfl)
    bar.frame_every = scene.output.every  # output times clip the step, as in hpcmpm's runner
    return bar


def run_peer_bar(bar, end_time: float, info: dict | None = None) -> float:
    """The peer from the initial particles to ``end_time``; its period error."""
    bar.reset()
    t, v = bar.run(end_time, bar.frame_every)
    if info is not None:
        info["steps"] = len(t)
    return bar_period_error(t, v)


def run_sim(scene, end_time, observer=None, setup=None) -> Simulation:
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    if setup is not None:
        setup(sim)
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=end_time, quiet=True),
           observer=observer).run()
    return sim


# -- (b) manufactured solution ------------------------------------------------------------------
MMS_A, MMS_MU, MMS_RHO = 0.05, 1.0, 1.0  # E = 2 mu with nu = 0


def mms_scene(cells: int, transfer: str, kernel: str, end_time: float, cfl: float = 0.2,
              ppc: int = 2):
    dx = 1.0 / cells
    height = 4 * dx
    text = f"""
[simulation]
dim = 2
domain = {{ lower = [0.0, 0.0], upper = [1.0, {height!r}] }}
dx = {dx!r}
particles_per_cell = {ppc}
kernel = "{kernel}"
transfer = "{transfer}"
cfl = {cfl!r}
end_time = {end_time!r}

[[materials]]
name = "mms"
type = "neo_hookean"
density = {MMS_RHO!r}
E = {2 * MMS_MU!r}
nu = 0.0

[[bodies]]
name = "bar"
material = "mms"
shape = "box"
lower = [0.0, 0.0]
upper = [1.0, {height!r}]

[walls]
default = "slip"
x_lower = {{ condition = "sticky" }}
x_upper = {{ condition = "sticky" }}
"""
    return parse_scene(text, path="<mms>")


def mms_u(X, t):
    return MMS_A * np.sin(2 * np.pi * X) * np.sin(np.pi * t)


def mms_body_force(X, t):
    """b = d2u/dt2 - (1/rho0) dP11/dX with P11 = mu (F - 1/F), F = 1 + du/dX."""
    s, c, st = np.sin(2 * np.pi * X), np.cos(2 * np.pi * X), np.sin(np.pi * t)
    F = 1.0 + MMS_A * 2 * np.pi * c * st
    dF = -MMS_A * (2 * np.pi) ** 2 * s * st
    dP = MMS_MU * (1.0 + 1.0 / F**2) * dF
    return -MMS_A * np.pi**2 * s * st - dP / MMS_RHO


def run_mms(cells: int, transfer: str, kernel: str, end_time: float = 1.0,
            ppc: int = 2) -> float:
    scene = mms_scene(cells, transfer, kernel, end_time, ppc=ppc)
    X0 = {}

    def setup(sim):
        p = sim.particles
        X = p["x"][:, 0].copy()
        X0["ids"] = p["id"].copy()
        X0["X"] = X
        # du/dt at t = 0 and its gradient (the affine field of APIC/MLS).
        p["v"][:, 0] = MMS_A * np.pi * np.sin(2 * np.pi * X)
        p["v"][:, 1] = 0.0
        if sim.scheme >= APIC:
            p["C"][:] = 0.0
            p["C"][:, 0, 0] = MMS_A * np.pi * 2 * np.pi * np.cos(2 * np.pi * X)
        order = np.argsort(X0["ids"])
        X0["sorted_ids"], X0["sorted_X"] = X0["ids"][order], X[order]

        def forcing(sim, dt):
            q = sim.particles
            Xq = X0["sorted_X"][np.searchsorted(X0["sorted_ids"], q["id"])]
            q["v"][:, 0] += dt * mms_body_force(Xq, sim.time)

        sim.forcing = forcing

    sim = run_sim(scene, end_time, setup=setup)
    p = sim.particles
    X = X0["sorted_X"][np.searchsorted(X0["sorted_ids"], p["id"])]
    err = p["x"][:, 0] - X - mms_u(X, sim.time)
    return float(np.sqrt(np.mean(err**2)) / MMS_A)


# -- driver -----------------------------------------------------------------------------------
def order_of(dxs, errors) -> float:
    dxs, errors = np.asarray(dxs, float), np.asarray(errors, float)
    ok = np.isfinite(errors) & (errors > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(dxs[ok]), np.log(errors[ok]), 1)[0])


def fastest(run, repeat: int) -> tuple[float, float]:
    """(result, seconds) of ``run()``, the seconds the least of ``repeat`` runs (the shared
    machine's noise only ever adds time); the result must be the same every run."""
    best, result = math.inf, None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        r = run()
        best = min(best, time.perf_counter() - t0)
        if result is not None and not (r == result or (math.isnan(r) and math.isnan(result))):
            raise RuntimeError(f"a repeated run gave {r!r}, the first {result!r}")
        result = r
    return result, best


def main(argv=None) -> int:
    global MMS_A
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, short runs")
    ap.add_argument("--cells", type=int, nargs="+", help="resolutions (cells along the bar)")
    ap.add_argument("--problems", nargs="+", choices=("bar", "mms"), default=["bar", "mms"],
                    help="which problems to run (default: both)")
    ap.add_argument("--repeat", type=int, default=None,
                    help="time each run this many times and keep the fastest (default 3; "
                         "1 with --smoke): the error is the same every time")
    ap.add_argument("--no-peer", action="store_true",
                    help="leave out the Taichi peer on the bar")
    ap.add_argument("--out-dir", default=str(REPO / "bench_results"))
    ap.add_argument("--png", default=str(REPO / "docs/img/study_error.png"))
    ap.add_argument("--mms-amplitude", type=float, default=MMS_A,
                    help="A of the manufactured solution (default %(default)s)")
    ap.add_argument("--mms-ppc", type=int, default=2,
                    help="MMS particles per cell per axis (default %(default)s); 4 tests the "
                         "quadrature-error explanation of the quadratic plateau")
    args = ap.parse_args(argv)
    MMS_A = args.mms_amplitude
    cells = args.cells or ([10, 20] if args.smoke else [25, 50, 100])
    repeat = args.repeat or (1 if args.smoke else 3)
    # The bar's domain [30, 2] must be a whole number of cells: 25 cells along the bar at least.
    bar_cells = [n for n in cells if (BAR_L / n) in (1.0, 0.5, 0.25, 0.125)] or [25, 50]
    bar_end = 8.0
    mms_end = 0.2 if args.smoke else 1.0
    transfers = TRANSFERS
    kernels = KERNELS
    problems = {"bar": (lambda n, tr, k, info: run_bar(n, tr, k, bar_end, info),
                        lambda n: BAR_L / n, bar_cells),
                "mms": (lambda n, tr, k, info: run_mms(n, tr, k, mms_end, args.mms_ppc),
                        lambda n: 1.0 / n,
                        cells)}
    problems = {name: problems[name] for name in ("bar", "mms") if name in args.problems}

    peer = None
    if "bar" in problems and not args.no_peer:
        peer = start_peer()
        if isinstance(peer, str):
            print(f"peer ({PEER}) skipped: {peer}", flush=True)
            peer = None

    # Warm-up: compile every (transfer, kernel) kernel once, so timings are run time only.
    for tr in transfers:
        for k in kernels:
            if "bar" in problems:
                run_bar(25, tr, k, 0.2)
            if "mms" in problems:
                run_mms(5, tr, k, 0.02)

    rows = []
    for name, (fn, dx_of, sizes) in problems.items():
        for tr in transfers:
            for k in kernels:
                for n in sizes:
                    info = {}
                    e, wall = fastest(lambda: fn(n, tr, k, info), repeat)
                    rows.append({"problem": name, "transfer": tr, "kernel": k, "cells": n,
                                 "dx": dx_of(n), "error": e, "wall_s": wall,
                                 "steps": info.get("steps", "")})
                    print(f"{name:4s} {tr:5s} {k:9s} {n:4d} cells  error {e:.4e}  "
                          f"wall {wall:.2f} s", flush=True)

    keys = [(name, tr, k) for name in problems for tr in transfers for k in kernels]
    if peer is not None:
        keys.append(("bar", PEER, "quadratic"))
        for n in bar_cells:
            bar = make_peer_bar(peer, n)  # fields only; each instance compiles its kernels
            run_peer_bar(bar, 0.2)  # warm-up: Taichi's JIT, not timed
            # hpcmpm's MLS/quadratic run again, alternating with the peer's (as
            # scripts/bench_peer.py does), so the two times see the same machine load.
            info, ref_info = {}, {}
            wall = wall_ref = math.inf
            for _ in range(repeat):
                e_ref, w = fastest(lambda: run_bar(n, "mls", "quadratic", bar_end, ref_info), 1)
                wall_ref = min(wall_ref, w)
                e, w = fastest(lambda: run_peer_bar(bar, bar_end, info), 1)
                wall = min(wall, w)
            rows.append({"problem": "bar", "transfer": PEER, "kernel": "quadratic", "cells": n,
                         "dx": BAR_L / n, "error": e, "wall_s": wall, "steps": info["steps"],
                         "hpcmpm_mls_wall_s": wall_ref})
            print(f"bar  {PEER} quadratic {n:4d} cells  error {e:.4e}  wall {wall:.3f} s  "
                  f"{info['steps']} steps; alternating with hpcmpm mls/quadratic: error "
                  f"{e_ref:.4e}, {ref_info['steps']} steps, wall {wall_ref:.3f} s "
                  f"(hpcmpm/peer throughput {wall / wall_ref:.2f}x)", flush=True)

    orders = {}
    for key in keys:
        sel = [r for r in rows if (r["problem"], r["transfer"], r["kernel"]) == key]
        orders[key] = order_of([r["dx"] for r in sel], [r["error"] for r in sel])
    for r in rows:
        r["order"] = orders[(r["problem"], r["transfer"], r["kernel"])]

    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "study_error.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {csv_path}")
    print("\nmeasured orders (slope of log error vs log dx):")
    for (name, tr, k), o in orders.items():
        print(f"  {name:4s} {tr:10s} {k:9s} {o:6.2f}")

    from hpcmpm.viz.plots import Curve, Panel, plot_panels

    colors = dict(zip(transfers, ("C0", "C1", "C2", "C3")))
    colors[PEER] = "k"
    styles = {"quadratic": "o-", "cubic": "s--"}
    panels = []
    for name in problems:
        curves = []
        for key in keys:
            if key[0] != name:
                continue
            _, tr, k = key
            sel = [r for r in rows if (r["problem"], r["transfer"], r["kernel"]) == key
                   and np.isfinite(r["error"]) and r["error"] > 0]
            if not sel:
                continue
            peer_row = tr == PEER
            curves.append(Curve([r["wall_s"] for r in sel], [r["error"] for r in sel],
                                f"{tr}/{k}{' (peer: Taichi)' if peer_row else ''} "
                                f"(order {orders[key]:.2f})",
                                "*:" if peer_row else styles[k], colors[tr],
                                11 if peer_row else 6))
        panels.append(Panel(curves, "wall time per run [s]",
                            "relative period error" if name == "bar"
                            else "RMS displacement error / A",
                            "axial bar (period)" if name == "bar"
                            else f"manufactured large deformation (A = {MMS_A})",
                            logx=True, logy=True, legend_size=7))
    png = plot_panels(Path(args.png), panels,
                      f"hpcmpm error vs cost, cells {cells}"
                      + (f"; bar also in the peer ({PEER})" if peer is not None else ""),
                      cols=len(panels), panel_size=(6.0, 5.0))
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

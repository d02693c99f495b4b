"""Channel flows of the semi-implicit integrator against closed forms (issue 9).

    python scripts/study_channels.py newtonian    # series solution at t = 1 and 10, CFL dt
    python scripts/study_channels.py bigdt        # the same with dt = 20x the viscous limit
    python scripts/study_channels.py order        # time order of the start-up at t = 0.5
    python scripts/study_channels.py bingham hb   # plug flows at t = 10: profile and plug width
    python scripts/study_channels.py hb --times 10 15 20 --set simulation.particles_per_cell=3
    python scripts/study_channels.py newtonian --times 5 10 15 20 25 30   # the growing mode
    python scripts/study_channels.py hb --times 10 15 20 25 30 --hold-rows  # without it
    python scripts/study_channels.py all [--smoke]

Scenes: inputs/channel_{newtonian,bingham,hb}_2d.toml (periodic x, sticky walls at y = 0, 1,
body force along +x as gravity, rho = g = 1). Errors are max over particles of
|v_x - u(y_p)| / u_max; the plug half-width is the largest |y - 1/2| of a particle that has not
yielded (|dev b| <= sigma_Y, the flow rule's own criterion) in the band around the centre.
Prints one line per result and writes them to bench_results/study_channels.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hpcmpm.runner import simulate  # noqa: E402
from hpcmpm.scene import load_scene  # noqa: E402

SCENES = {k: str(ROOT / "inputs" / f"channel_{k}_2d.toml")
          for k in ("newtonian", "bingham", "hb")}


def newtonian_profile(y, t, nu=0.1, g=1.0, terms=400):
    """Start-up of plane Poiseuille flow from rest (issue 9)."""
    u = g * y * (1 - y) / (2 * nu)
    for k in range(1, 2 * terms, 2):
        u = u - 4 * g / (nu * math.pi ** 3 * k ** 3) * np.sin(k * math.pi * y) * \
            math.exp(-k * k * math.pi ** 2 * nu * t)
    return u


def plug_profile(y, n, K=0.1, tau_y=0.1, rho_g=1.0):
    """Steady Herschel-Bulkley channel flow: plug |y - 1/2| <= y0 = tau_y / (rho g)."""
    y0 = tau_y / rho_g
    s = np.abs(y - 0.5)
    a = (n + 1) / n
    return n / (n + 1) * (rho_g / K) ** (1 / n) * ((0.5 - y0) ** a
                                                  - np.maximum(s - y0, 0.0) ** a)


def plug_half_width(p, sigma_y):
    """The plug's half-width: the largest |y - 1/2| of the unyielded particles (|dev b| <=
    sigma_Y, the flow rule's own criterion) in the band around the centre that the first
    yielded particle, going out from the centre, ends; 0 when the centre has yielded."""
    b = p["b"]
    d = b.shape[1]
    dev = b - np.trace(b, axis1=1, axis2=2)[:, None, None] / d * np.eye(d)
    unyielded = np.sqrt(np.einsum("pij,pij->p", dev, dev)) <= sigma_y * (1 + 1e-9)
    s = np.abs(p["x"][:, 1] - 0.5)
    order_s = np.argsort(s)
    first_yielded = np.argmax(~unyielded[order_s]) if (~unyielded).any() else len(s)
    return float(s[order_s][first_yielded - 1]) if first_yielded else 0.0


def hold_rows(sim):
    """Put every particle back on its lattice row across the channel (y only; its x, v and
    state are left as they are): the flow's rows still slide past each other along x, but
    no particle drifts across the streamlines. The held-rows experiment of docs/studies.md,
    which keeps the wall layers' mode away; an observer for studies, not part of the scene."""
    h = sim.dx / sim.scene.particles_per_cell
    y = sim.particles["x"][:, 1]
    y[:] = (np.rint(y / h - 0.5) + 0.5) * h


def run_to(scene_path, times, overrides=(), hold=False):
    """Simulate and return {t: (y, vx, particle fields copy)} at each of ``times``; ``hold``
    holds the particles on their rows after every step (`hold_rows`)."""
    times = sorted(times)
    every = times[0] if len(times) == 1 else min(np.diff([0.0] + times))
    scene = load_scene(scene_path, [f"simulation.end_time={times[-1]}",
                                    f"output.every={every}", *overrides])
    snaps, cg = {}, []

    def observe(sim):
        if hold:
            hold_rows(sim)
        cg.append(getattr(sim.integrator, "last_step", {}).get("cg_iterations", 0))
        for t in times:
            if abs(sim.time - t) < 1e-9 * max(t, 1) and t not in snaps:
                p = sim.particles
                snaps[t] = {k: p[k].copy() for k in p.field_names()}

    start = time.perf_counter()
    sim = simulate(scene, observer=observe)
    wall = time.perf_counter() - start
    return snaps, sim, wall, cg


def newtonian(results, smoke, overrides=(), label="newtonian", times=None):
    times = [0.25] if smoke else sorted(times or [1.0, 10.0])
    snaps, sim, wall, cg = run_to(SCENES["newtonian"], times, overrides)
    for t in times:
        p = snaps[t]
        y, vx, vy = p["x"][:, 1], p["v"][:, 0], p["v"][:, 1]
        err = np.abs(vx - newtonian_profile(y, t)).max() / 1.25
        results[f"{label}_t{t:g}_error_over_umax"] = err
        results[f"{label}_t{t:g}_max_abs_vy"] = float(np.abs(vy).max())
        # |v_y| is 0 in the exact flow: the channels' growing mode (docs/studies.md).
        print(f"{label}: t = {t:g}: max |u - u_series| / u_max = {err:.4f}; "
              f"max |v_y| {np.abs(vy).max():.2e}")
    results[f"{label}_steps"] = sim.step_index
    results[f"{label}_wall_s"] = wall
    results[f"{label}_cg_mean_max"] = [float(np.mean(cg)), int(max(cg))]
    print(f"{label}: {sim.step_index} steps in {wall:.1f} s; CG per step mean "
          f"{np.mean(cg):.1f}, max {max(cg)}")


def bigdt(results, smoke):
    dx = 1.0 / 64
    limit = 1.0 * dx * dx / (2 * 2 * 0.1)  # explicit viscous limit rho dx^2/(2 d mu_N)
    dt = 20 * limit
    results["bigdt_dt"] = dt
    print(f"bigdt: dt = {dt:.5g} = 20 x the explicit viscous limit {limit:.4g}")
    newtonian(results, smoke, [f"simulation.dt={dt}"], label="newtonian_dt20x")


def order(results, smoke):
    """Self-convergence in dt at t = 0.5: e(dt) = max|u_dt - u_dt/2|; order log2 of the ratio
    of successive e (removes the dt-independent spatial error)."""
    t = 0.25 if smoke else 0.5
    dts = [0.05, 0.025, 0.0125] if smoke else [0.05, 0.025, 0.0125, 0.00625]
    profiles = []
    for dt in dts:
        snaps, sim, _, _ = run_to(SCENES["newtonian"], [t], [f"simulation.dt={dt}"])
        p = snaps[t]
        order_ids = np.argsort(p["id"])
        profiles.append(p["v"][order_ids, 0])
        err = np.abs(p["v"][order_ids, 0] - newtonian_profile(p["x"][order_ids, 1], t)).max()
        print(f"order: dt = {dt:g}: max |u - u_series| / u_max = {err / 1.25:.5f}")
    diffs = [np.abs(a - b).max() for a, b in zip(profiles, profiles[1:])]
    orders = [math.log2(a / b) for a, b in zip(diffs, diffs[1:])]
    results["order_dts"] = dts
    results["order_differences"] = diffs
    results["order_slopes"] = orders
    print(f"order: successive differences {['%.3e' % d for d in diffs]}, orders "
          f"{['%.3f' % o for o in orders]}")


def plug(results, smoke, name, n, overrides=(), label=None, times=(10.0,), hold=False):
    times = [1.0] if smoke else sorted(times)
    snaps, sim, wall, cg = run_to(SCENES[name], times, overrides, hold)
    name = label or name
    dx = sim.dx
    for t in times:
        p = snaps[t]
        y, vx, vy = p["x"][:, 1], p["v"][:, 0], p["v"][:, 1]
        expected = plug_profile(y, n)
        umax = expected.max()
        err = np.abs(vx - expected).max() / umax
        half_width = plug_half_width(p, sim.materials[0].sigma_y)
        results[f"{name}_t{t:g}_error_over_umax"] = err
        results[f"{name}_t{t:g}_max_abs_vy"] = float(np.abs(vy).max())
        results[f"{name}_plug_half_width" + ("" if t == times[-1] else f"_t{t:g}")] = half_width
        # |v_y| is 0 in the exact flow: it measures the wall layers' mode (docs/studies.md).
        print(f"{name}: t = {t:g}: max |u - u_exact| / u_max = {err:.4f} (u_max {umax:.4f}, "
              f"measured {vx.max():.4f}); plug half-width {half_width:.4f} vs 0.1 "
              f"({abs(half_width - 0.1) / dx:.2f} dx); max |v_y| {np.abs(vy).max():.2e}")
    results[f"{name}_plug_error_in_dx"] = abs(half_width - 0.1) / dx
    results[f"{name}_steps"] = sim.step_index
    results[f"{name}_wall_s"] = wall
    results[f"{name}_cg_mean_max"] = [float(np.mean(cg)), int(max(cg or [0]))]
    print(f"{name}: {sim.step_index} steps in {wall:.1f} s; "
          f"CG per step mean {np.mean(cg):.1f}, max {max(cg or [0])}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="+",
                        choices=["newtonian", "bigdt", "order", "bingham", "hb", "all"])
    parser.add_argument("--smoke", action="store_true", help="short runs (CI smoke)")
    parser.add_argument("--explicit", action="store_true",
                        help="plug flows with the explicit integrator instead (reference)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="scene override for the plug flows, e.g. simulation.dt=0.02 or "
                             "materials.0.flow_update=\"explicit\" (repeatable)")
    parser.add_argument("--tag", default="", help="suffix of the plug flows' result names")
    parser.add_argument("--hold-rows", action="store_true",
                        help="plug flows with every particle held on its row across the "
                             "channel after each step (the held-rows experiment)")
    parser.add_argument("--times", type=float, nargs="+", default=None,
                        help="times at which the newtonian and plug flows are compared "
                             "(default 1 and 10, and 10)")
    args = parser.parse_args(argv)
    what = ["newtonian", "bigdt", "order", "bingham", "hb"] if "all" in args.what else args.what
    results = {}
    for item in what:
        if item == "newtonian":
            newtonian(results, args.smoke, args.set, "newtonian" + args.tag, args.times)
        elif item == "bigdt":
            bigdt(results, args.smoke)
        elif item == "order":
            order(results, args.smoke)
        elif item in ("bingham", "hb"):
            n = 1.0 if item == "bingham" else 0.5
            overrides = list(args.set)
            label = item + ("_explicit" if args.explicit else "") + \
                ("_held_rows" if args.hold_rows else "") + args.tag
            if args.explicit:
                overrides.append('simulation.integrator="explicit"')
            plug(results, args.smoke, item, n, overrides, label, args.times or [10.0],
                 args.hold_rows)
    out = ROOT / "bench_results"
    out.mkdir(exist_ok=True)
    path = out / ("study_channels_smoke.json" if args.smoke else "study_channels.json")
    previous = json.loads(path.read_text()) if path.exists() else {}
    previous.update(results)
    path.write_text(json.dumps(previous, indent=1, default=float))
    return results


if __name__ == "__main__":
    main()

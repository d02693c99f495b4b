"""Semi-implicit against explicit (issue 9): wall time to the same simulated time with an
observable that agrees to 1 %, CG iterations per step with and without Jacobi, and the cost of
one Hessian-vector product against one explicit step's transfers.

    python scripts/bench_semi_implicit.py                      # everything, full scenes
    python scripts/bench_semi_implicit.py speedup --scene pie_2d --end-time 0.2
    python scripts/bench_semi_implicit.py cg                   # Jacobi against none
    python scripts/bench_semi_implicit.py hessian              # H u against P2G + G2P
    python scripts/bench_semi_implicit.py all --smoke          # tiny, for CI
    python scripts/bench_semi_implicit.py steps --scene toothpaste_3d --dt 1e-3 5e-4 2.5e-4 \
        --transfer apic pic --set simulation.dx=0.025  # the observable against the step

Each measurement runs in this process after a warm-up run that compiles every kernel (the
numba cache makes it short the second time), one rank. ``speedup``: the scene to
``--end-time`` with ``simulation.integrator`` set to "explicit" (its CFL and viscous bounds)
and to "semi_implicit" (advection bound); wall time of the time loop alone, the observable
(OBSERVABLES below) of both and their relative difference. ``cg``: mean and max CG iterations
per step of the semi-implicit run with preconditioner "jacobi" and "none". ``hessian``: the
mean wall time of `SemiImplicitIntegrator._hessian` (fill ghosts, the fused contraction /
tangent / scatter loop, sum to owners, mass term, mask) over ``--repeats`` calls, and of the
tangents it uses (`_tangent`: d^2 material Hessian products, once per linearization), against
the mean p2g + g2p time of an explicit step of the same scene and state. ``steps`` (not in
``all``): the observable of both integrators at each fixed ``--dt`` and each ``--transfer``,
to the same end time, so the observable's own dependence on the step (each P2G/G2P transfer
dissipates, whatever the integrator) is measured beside the semi-implicit step's. Writes
bench_results/semi_implicit.json (``steps`` alone: semi_implicit_steps.json). Timings on a
shared, loaded host are noise: run on a quiet machine before quoting them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hpcmpm.errors import InstabilityError  # noqa: E402
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain  # noqa: E402
from hpcmpm.scene import load_scene  # noqa: E402
from hpcmpm.simulation import Simulation  # noqa: E402
from hpcmpm.solvers.semi_implicit import SolverFailure  # noqa: E402

SCENES = ("pie_2d", "toothpaste_3d", "sponge_twist_ob_3d")
END_TIMES = {"pie_2d": 0.2, "toothpaste_3d": 0.4, "sponge_twist_ob_3d": 0.2}
CG_SCENES = ("sponge_bullet_ob_3d", "pie_2d", "toothpaste_3d", "sponge_twist_ob_3d")


def centre_of_mass(sim, material=None):
    p = sim.particles
    sel = slice(None) if material is None else p["group"] == material
    m = p["mass"][sel]
    return (m[:, None] * p["x"][sel]).sum(axis=0) / m.sum()


# One number per scene that both integrators must reproduce (relative difference <= 1 %):
# pie: how far the cream's centre has travelled along the throw; toothpaste: the height of
# its centre of mass above the box top; sponge: its elastic energy under the twist.
OBSERVABLES = {
    "pie_2d": ("cream centre of mass x - x0", lambda sim, x0: centre_of_mass(sim, 0)[0] - x0[0]),
    "toothpaste_3d": ("centre of mass height above the box top",
                      lambda sim, x0: centre_of_mass(sim)[1] - 0.3),
    "sponge_twist_ob_3d": ("elastic energy", lambda sim, x0: sim.diagnostics()["elastic_energy"]),
}


def build(scene_name, overrides):
    scene = load_scene(str(ROOT / "inputs" / f"{scene_name}.toml"), list(overrides))
    sim = Simulation(scene, make_domain(scene))
    initial_particles(sim)
    return sim


def run(scene_name, end_time, overrides=(), record=None):
    """(wall seconds of the loop, steps, simulation, per-step CG iterations); ``record`` (a
    dict) gets ``above_bound``: a fixed dt was past the integrator's stable step."""
    sim = build(scene_name, [f"simulation.end_time={end_time}", f"output.every={end_time}",
                             *overrides])
    x0 = centre_of_mass(sim, 0)
    cg = []

    def observe(s):
        cg.append(getattr(s.integrator, "last_step", {}).get("cg_iterations", 0))

    options = RunOptions(out_dir=Path("."), end_time=end_time, quiet=True)
    start = time.perf_counter()
    runner = Runner(sim, None, options, observer=observe)
    runner.run()
    if record is not None:
        record["above_bound"] = runner.dt_warned
    return time.perf_counter() - start, sim.step_index, sim, cg, x0


def speedup(results, scenes, end_times, smoke):
    for name in scenes:
        end = end_times[name]
        extra = ["simulation.dx=0.05"] if smoke and name.endswith("3d") else []
        label, observable = OBSERVABLES[name]
        row = {"end_time": end, "observable": label}
        for integrator in ("explicit", "semi_implicit"):
            overrides = [f'simulation.integrator="{integrator}"', *extra]
            run(name, min(end, 1e-4), overrides)  # warm-up: compile
            wall, steps, sim, cg, x0 = run(name, end, overrides)
            value = float(observable(sim, x0))
            row[integrator] = {"wall_s": wall, "steps": steps, "observable": value}
            if integrator == "semi_implicit":
                row[integrator]["cg_mean"] = float(np.mean(cg))
                row[integrator]["cg_max"] = int(max(cg))
            print(f"speedup {name} {integrator}: {steps} steps, {wall:.2f} s, {label} = "
                  f"{value:.6g}", flush=True)
        e, s = row["explicit"], row["semi_implicit"]
        row["speedup"] = e["wall_s"] / s["wall_s"]
        row["observable_relative_difference"] = abs(s["observable"] - e["observable"]) / \
            max(abs(e["observable"]), 1e-300)
        print(f"speedup {name}: {row['speedup']:.2f}x, observable differs by "
              f"{100 * row['observable_relative_difference']:.2f} %", flush=True)
        results.setdefault("speedup", {})[name] = row


def cg(results, scenes, end_times, smoke):
    for name in scenes:
        end = end_times.get(name, 0.1)
        extra = ["simulation.dx=0.05"] if smoke and name.endswith("3d") else []
        row = {"end_time": end}
        for preconditioner in ("jacobi", "none"):
            overrides = [f'solver.preconditioner="{preconditioner}"', *extra]
            try:
                wall, steps, sim, counts, _ = run(name, end, overrides)
            except SolverFailure as failure:  # e.g. no preconditioner on a stiff scene
                row[preconditioner] = {"failed": str(failure)}
                print(f"cg {name} {preconditioner}: {failure}", flush=True)
                continue
            row[preconditioner] = {"cg_mean": float(np.mean(counts)),
                                   "cg_max": int(max(counts)), "steps": steps, "wall_s": wall}
            print(f"cg {name} {preconditioner}: mean {np.mean(counts):.1f}, max "
                  f"{max(counts)} over {steps} steps", flush=True)
        if "cg_mean" in row["none"] and "cg_mean" in row["jacobi"]:
            row["ratio_mean"] = row["none"]["cg_mean"] / max(row["jacobi"]["cg_mean"], 1e-300)
        results.setdefault("cg", {})[name] = row


def steps(results, scenes, end_times, dts, transfers, sets):
    """The observable of each integrator and transfer at each fixed step, same end time."""
    for name in scenes:
        end = end_times[name]
        label, observable = OBSERVABLES[name]
        rows = []
        for transfer in transfers:
            for integrator in ("explicit", "semi_implicit"):
                for dt in dts:
                    overrides = [f'simulation.integrator="{integrator}"',
                                 f'simulation.transfer="{transfer}"', f"simulation.dt={dt}",
                                 *sets]
                    flags = {}
                    try:
                        wall, n, sim, _, x0 = run(name, end, overrides, flags)
                    except InstabilityError as failure:  # explicit past its stable step
                        rows.append({"transfer": transfer, "integrator": integrator,
                                     "dt": dt, "failed": str(failure).splitlines()[0]})
                        print(f"steps {name} {transfer} {integrator} dt = {dt:g}: unstable",
                              flush=True)
                        continue
                    value = float(observable(sim, x0))
                    rows.append({"transfer": transfer, "integrator": integrator, "dt": dt,
                                 "steps": n, "observable": value, "wall_s": wall, **flags})
                    past = " (dt past the stable step)" if flags["above_bound"] else ""
                    print(f"steps {name} {transfer} {integrator} dt = {dt:g}: {n} steps, "
                          f"{label} = {value:.6g} ({wall:.1f} s){past}", flush=True)
        results.setdefault("steps", {})[name] = {"end_time": end, "observable": label,
                                                 "sets": list(sets), "runs": rows}


def hessian(results, scenes, repeats, smoke):
    for name in scenes:
        extra = ["simulation.dx=0.05"] if smoke and name.endswith("3d") else []
        # Explicit transfers: P2G (with the stress) and G2P per step.
        sim = build(name, ['simulation.integrator="explicit"', *extra])
        dt = sim.stable_dt()
        for _ in range(3):
            sim.step(dt)  # compile, settle
        sim.timers.reset()
        steps = 10
        for _ in range(steps):
            sim.step(dt)
        transfers = (sim.timers.seconds["p2g"] + sim.timers.seconds["g2p"]) / steps
        # One Hessian-vector product of the semi-implicit solve on the same scene.
        sim = build(name, extra)
        dt = sim.stable_dt()
        sim.step(dt)
        integ = sim.integrator
        sim.sort_phase()
        sim.fit_grid()
        sim.scatter_mass_momentum()
        sim.sum_ghosts()
        integ._prepare(sim, dt)
        integ._gradient(sim, dt)
        rng = np.random.default_rng(0)
        integ._flat["cg_u"][:] = rng.standard_normal(integ._flat["cg_u"].shape)
        integ._project("cg_u")
        integ._hessian(sim, dt, "cg_u", "cg_w")  # compiled
        # The tangents (d^2 material products, once per linearization), then the product a
        # CG iteration applies with them.
        start = time.perf_counter()
        for _ in range(repeats):
            integ._tangent_ready = False
            integ._tangent(sim, dt)
        tangent = (time.perf_counter() - start) / repeats
        start = time.perf_counter()
        for _ in range(repeats):
            integ._hessian(sim, dt, "cg_u", "cg_w")
        product = (time.perf_counter() - start) / repeats
        row = {"hessian_product_s": product, "tangent_s": tangent,
               "explicit_transfers_s": transfers, "ratio": product / transfers,
               "tangent_ratio": tangent / transfers, "particles": int(sim.particles.n)}
        print(f"hessian {name}: H u {1e3 * product:.3f} ms, tangents {1e3 * tangent:.3f} ms "
              f"(once per linearization), explicit P2G + G2P {1e3 * transfers:.3f} ms, ratio "
              f"{product / transfers:.2f}", flush=True)
        results.setdefault("hessian", {})[name] = row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="*", default=["all"],
                        choices=["speedup", "cg", "hessian", "steps", "all"])
    parser.add_argument("--scene", action="append", help="limit to these scenes")
    parser.add_argument("--end-time", type=float, help="simulated time of the speedup runs")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--smoke", action="store_true", help="tiny sizes and times (CI)")
    parser.add_argument("--dt", type=float, nargs="+", default=[1e-3, 5e-4, 2.5e-4],
                        help="fixed steps of the `steps` study")
    parser.add_argument("--transfer", nargs="+", default=["apic"],
                        help="transfers of the `steps` study")
    parser.add_argument("--set", action="append", default=[], dest="sets",
                        help="scene overrides of the `steps` study (KEY=VALUE)")
    args = parser.parse_args(argv)
    what = {"speedup", "cg", "hessian"} if "all" in args.what else set(args.what)
    end_times = dict(END_TIMES)
    if args.smoke:  # a few steps (the explicit pie alone takes 1000 at 1e-6)
        end_times = {k: 1e-3 for k in set(END_TIMES) | set(CG_SCENES)}
    if args.end_time:
        end_times = {k: args.end_time for k in set(END_TIMES) | set(CG_SCENES)}
    results = {"smoke": args.smoke}
    if "speedup" in what:
        speedup(results, args.scene or SCENES, end_times, args.smoke)
    if "cg" in what:
        cg(results, args.scene or CG_SCENES, end_times, args.smoke)
    if "steps" in args.what:
        sets = args.sets + (["simulation.dx=0.05"] if args.smoke else [])
        steps(results, args.scene or ["toothpaste_3d"], end_times,
              args.dt[:1] if args.smoke else args.dt, args.transfer, sets)
    if "hessian" in what:
        hessian(results, args.scene or SCENES, 3 if args.smoke else args.repeats, args.smoke)
    out = ROOT / "bench_results"
    out.mkdir(exist_ok=True)
    # The step study alone writes a file of its own, so it does not replace the speed-ups.
    name = "semi_implicit_steps" if set(args.what) == {"steps"} else "semi_implicit"
    name += "_smoke.json" if args.smoke else ".json"
    (out / name).write_text(json.dumps(results, indent=1, default=float))
    return results


if __name__ == "__main__":
    main()

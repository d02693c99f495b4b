"""What SPB-MPM's grid energy (003 eq. 6.10) costs an MPM scene that never converts, and the
PD share of a step once it does (003 Fig. 6.9 reports 14.4 %).

Runs a scene three ways, in one process, same steps: as written but with G_EE out of reach
(eq. 6.10 every step, no conversion), without its `failure` tables (plain MPM), and as
written (conversions, PD). Prints wall time per step and the phase shares. Timings on a
shared machine are noisy: run it on a quiet one.

    python scripts/bench_spb_overhead.py inputs/spb_stretched_bar_2d.toml --steps 400
    mpiexec -n 2 python scripts/bench_spb_overhead.py inputs/spb_chocolate_drop_3d.toml
"""

from __future__ import annotations

import argparse
import time
import tomllib

import tomli_w

from hpcmpm.parallel import Communicator
from hpcmpm.runner import initial_particles, make_domain
from hpcmpm.scene import parse_scene
from hpcmpm.simulation import Simulation


def variant(text: str, kind: str) -> str:
    raw = tomllib.loads(text)
    for m in raw["materials"]:
        if "failure" in m:
            if kind == "mpm":
                del m["failure"]
            elif kind == "unreached":
                m["failure"]["grid_energy"] = 1e300
    return tomli_w.dumps(raw)


def measure(text: str, path: str, steps: int, warm: int, comm) -> tuple[float, object]:
    scene = parse_scene(text, path)
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    dt = sim.stable_dt()
    for _ in range(warm):                  # compile and settle before timing
        sim.step(dt)
    sim.timers.reset()
    comm.barrier()
    start = time.perf_counter()
    for _ in range(steps):
        sim.step(min(dt, sim.stable_dt()))
    comm.barrier()
    return (time.perf_counter() - start) / steps, sim


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--warm", type=int, default=20)
    args = ap.parse_args()
    comm = Communicator()
    text = open(args.scene).read()
    rows = {}
    for kind in ("mpm", "unreached", "as_written"):
        rows[kind] = measure(variant(text, kind) if kind != "as_written" else
                             tomli_w.dumps(tomllib.loads(text)), args.scene, args.steps,
                             args.warm, comm)
    totals = {kind: sim.domain.sum(sim.particles.n) for kind, (_, sim) in rows.items()}
    if comm.rank:
        return
    base = rows["mpm"][0]
    for kind, (per_step, sim) in rows.items():
        t = sim.timers
        total = t.total() or 1.0
        share = lambda *names: sum(t.seconds.get(n, 0.0) for n in names) / total  # noqa
        ext = sim.extensions[0] if sim.extensions else None
        print(f"{kind:10s} {1e3 * per_step:8.2f} ms/step ({per_step / base - 1:+.1%} vs MPM); "
              f"eq. 6.10 + flags {share('spb_energy', 'spb_convert'):.1%}, PD "
              f"{share('pd'):.1%}, re-transfer {share('spb_retransfer'):.1%}; PD particles "
              f"{ext.pd_global if ext else 0} of {totals[kind]}")


if __name__ == "__main__":
    main()

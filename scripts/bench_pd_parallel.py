"""2-rank efficiency of a 3D PD body (PMB, integration "pd" as DistributedPDBody).

A 3D lattice block (``--n`` points per axis), small random velocities, ``--steps`` steps after
two warm-up steps; prints the wall time per step (max over ranks) and, run as
``mpiexec -n 1`` and ``-n 2``, the caller computes efficiency = t1 / (2 t2). Also prints the
PD halo size and how often the plan was rebuilt.

    mpiexec -n 2 python scripts/bench_pd_parallel.py --n 24 --steps 30
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hpcmpm.parallel import Domain
from hpcmpm.pd.distributed import DistributedPDBody
from hpcmpm.pd.moduli import pmb_micromodulus
from hpcmpm.pd.pmb import PMB
from hpcmpm.state import SCALAR, VECTOR, FieldSpec, ParticleSet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--steps", type=int, default=30)
    args = ap.parse_args()
    n = args.n
    g = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64)] * 3, indexing="ij"),
                 -1).reshape(-1, 3) + 0.5
    ids = np.arange(len(g), dtype=np.int64)
    rng = np.random.default_rng(0)
    v = 1e-3 * rng.standard_normal(g.shape)
    domain = Domain(3, 2.0, [0.0] * 3, [float(n)] * 3)
    p = ParticleSet(3, {"x0": FieldSpec(VECTOR), "pd_wvol0": FieldSpec(SCALAR)})
    mine = np.flatnonzero(ids % domain.size == domain.rank)
    p.append({"id": ids[mine], "x": g[mine], "x0": g[mine], "v": v[mine],
              "mass": np.ones(len(mine)), "vol0": np.ones(len(mine))})
    domain.decompose(p)
    model = PMB(pmb_micromodulus(3, 1.0, 3.015), 0.05)
    body = DistributedPDBody(domain, p, model, 1.0, 3.015)
    dt = body.stable_dt()
    for _ in range(2):
        body.step(dt)
    domain.barrier()
    t = time.perf_counter()
    for _ in range(args.steps):
        body.step(dt)
    domain.barrier()
    wall = domain.max(time.perf_counter() - t) / args.steps
    bonds = domain.sum(int(body.bonds.n_bonds))
    halo = domain.sum(int(body.halo.n_halo))
    if domain.rank == 0:
        print(f"ranks {domain.size}: {len(g)} particles, {bonds} half-bonds, halo {halo}, "
              f"{wall * 1e3:.2f} ms/step, {bonds / wall / 1e6:.1f} M half-bond updates/s, "
              f"plan builds {body.halo.builds}")


if __name__ == "__main__":
    main()

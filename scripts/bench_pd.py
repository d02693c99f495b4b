"""PD force-phase throughput against a minimal fused numba ceiling (issue 10, Performance).

64k particles on a cubic lattice (40^3), delta = 3.015 dx, float64, one core. The ceiling is
the least a PMB force loop must do: a neighbour list (int32) and a reference length (float64)
per half-bond, positions, one accumulation per particle; the LPS ceiling adds the dilatation
pass. hpcmpm's kernels (hpcmpm.pd.pmb, hpcmpm.pd.lps) run on the same lattice with the family
truncated at delta (~112 half-bonds per particle, as the ceiling) and with PA-HHB partial
volumes (the default, ~166 per particle). Prints half-bond updates per second (best of
``--repeat`` calls, process CPU time), the family search time in force steps, and bytes per half-bond.

    NUMBA_NUM_THREADS=1 python scripts/bench_pd.py [--n 40] [--repeat 10]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from numba import njit

from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDPoints
from hpcmpm.pd.lps import LPS, lps_dilatation, lps_forces
from hpcmpm.pd.moduli import pmb_micromodulus
from hpcmpm.pd.pmb import pmb_forces


@njit(cache=True)
def ceiling_pmb(x, offsets, nbr, r0, c, f):
    for p in range(x.shape[0]):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            q = nbr[b]
            y0 = x[q, 0] - x[p, 0]
            y1 = x[q, 1] - x[p, 1]
            y2 = x[q, 2] - x[p, 2]
            yl = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            a = c * (yl - r0[b]) / (r0[b] * yl)
            f0 += a * y0
            f1 += a * y1
            f2 += a * y2
        f[p, 0] = f0
        f[p, 1] = f1
        f[p, 2] = f2


@njit(cache=True)
def ceiling_lps(x, offsets, nbr, r0, m, kappa, alpha, theta, f):
    n = x.shape[0]
    for p in range(n):
        s = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            q = nbr[b]
            y0 = x[q, 0] - x[p, 0]
            y1 = x[q, 1] - x[p, 1]
            y2 = x[q, 2] - x[p, 2]
            s += r0[b] * (math.sqrt(y0 * y0 + y1 * y1 + y2 * y2) - r0[b])
        theta[p] = 3.0 * s / m[p]
    for p in range(n):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[p], offsets[p + 1]):
            q = nbr[b]
            y0 = x[q, 0] - x[p, 0]
            y1 = x[q, 1] - x[p, 1]
            y2 = x[q, 2] - x[p, 2]
            yl = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            e = yl - r0[b]
            t = (3.0 * kappa * (theta[p] / m[p] + theta[q] / m[q]) * r0[b]
                 + alpha * (e - theta[p] * r0[b] / 3.0) / m[p]
                 + alpha * (e - theta[q] * r0[b] / 3.0) / m[q])
            a = t / yl
            f0 += a * y0
            f1 += a * y1
            f2 += a * y2
        f[p, 0] = f0
        f[p, 1] = f1
        f[p, 2] = f2


# CPU time of this process, not wall time: on a shared, oversubscribed machine the wall clock
# also counts the time other processes held the core.
clock = time.process_time


def best_rate(fn, n_bonds, repeat):
    fn()                                   # compile / warm the caches
    times = []
    for _ in range(repeat):
        t = clock()
        fn()
        times.append(clock() - t)
    return n_bonds / min(times), min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="lattice points per axis")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--json", help="also write the numbers to this file")
    args = ap.parse_args()
    results = {}
    n = args.n
    g = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64)] * 3, indexing="ij"),
                 -1).reshape(-1, 3)
    ids = np.arange(len(g), dtype=np.int64)
    vol = np.ones(len(g))
    rng = np.random.default_rng(0)
    x = g * 1.001 + 1e-4 * rng.standard_normal(g.shape)
    f = np.empty_like(g)
    delta = 3.015
    c = pmb_micromodulus(3, 1.0, delta)
    print(f"{len(g)} particles, delta = {delta} dx, one core")
    for pv in (False, True):
        find_families(g[:1000], ids[:1000], 1000, 1.0, delta, partial_volumes=pv)  # compile
        t = clock()
        fam = find_families(g, ids, len(g), 1.0, delta, partial_volumes=pv)
        t_search = clock() - t
        b = fam.bonds
        nb = b.n_bonds
        label = "partial volumes (PA-HHB)" if pv else "truncated at delta"
        print(f"\nfamily {label}: {nb / len(g):.1f} half-bonds/particle, "
              f"{b.resident_bytes_per_bond()} B resident per half-bond "
              f"({b.nbytes() / nb:.2f} B with offsets), search {t_search:.3f} s")
        slot = b.slot
        owner = np.repeat(np.arange(len(g)), b.counts())
        r0 = np.linalg.norm(g[slot] - g[owner], axis=1)
        rate_c, t_c = best_rate(lambda: ceiling_pmb(x, b.offsets, slot, r0, c, f), nb,
                                args.repeat)
        rate_p, t_p = best_rate(lambda: pmb_forces(x, g, vol, b.offsets, slot, b.status,
                                                   b.weight, c, math.inf, len(g), f), nb,
                                args.repeat)
        lps = LPS(1.0, 0.6)
        pts = PDPoints(g, x, vol, ids, len(g), b)
        lps.setup(pts)
        theta = np.zeros(len(g))
        m = pts.fields["m"]
        rate_cl, _ = best_rate(lambda: ceiling_lps(x, b.offsets, slot, r0, m, 1.0, 9.0, theta,
                                                   f), nb, args.repeat)

        def lps_step():
            lps_dilatation(x, g, vol, b.offsets, slot, b.status, b.weight, m, math.inf,
                           len(g), theta)
            lps_forces(x, g, vol, b.offsets, slot, b.status, b.weight, m, theta, 1.0, 0.6,
                       len(g), f)

        rate_l, _ = best_rate(lps_step, nb, args.repeat)
        print(f"  PMB ceiling  {rate_c / 1e6:7.1f} M half-bond updates/s")
        print(f"  PMB hpcmpm   {rate_p / 1e6:7.1f} M/s  ratio {rate_p / rate_c:.2f}")
        print(f"  LPS ceiling  {rate_cl / 1e6:7.1f} M/s (two passes)")
        print(f"  LPS hpcmpm   {rate_l / 1e6:7.1f} M/s  ratio {rate_l / rate_cl:.2f}")
        print(f"  neighbour search = {t_search / t_p:.1f} PMB force steps")
        results["partial_volumes" if pv else "truncated"] = {
            "half_bonds_per_particle": nb / len(g),
            "bytes_per_half_bond": b.resident_bytes_per_bond(),
            "pmb_ceiling": rate_c, "pmb": rate_p, "lps_ceiling": rate_cl, "lps": rate_l,
            "search_s": t_search, "search_in_force_steps": t_search / t_p}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"particles": len(g), "delta": delta, **results}, fh, indent=1)


if __name__ == "__main__":
    main()

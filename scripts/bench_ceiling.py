"""The ceiling: a minimal fused numba MLS-MPM step, and hpcmpm's throughput as a fraction of it.

The fused step is what a single-material, single-process, fixed-scene MLS-MPM code can do with
the same tools (numba, float64, quadratic B-splines, one thread): one function per scene kind
with the dimension, the kernel order and the material fixed at compile time, the stress
computed inside the P2G loop (no tau array), mass and momentum interleaved in one grid array,
the stencil loops of constant length 3 (unrolled by LLVM) over unsigned node indices (no
negative-index wraparound: `hpcmpm.kernels.shape.node`), scalars only inside the particle
loops, no allocation, no sort, no ghost exchange, a dense grid over the whole box. The 3D
fixed corotated rotation is hpcmpm's own `polar3` (scaled Newton), so the ratio measures the
cost of the framework around the physics, not a different polar decomposition; the 2D rotation
is the closed form.

hpcmpm and the ceiling run the same scene (scripts/bench_common.py) alternately in this one
process, repetitions A, B, A, B, ...; the report gives ms/step (min, median), particle-steps/s
and hpcmpm/ceiling (>= 0.75 is the target). Writes bench_results/ceiling.json.

    python scripts/bench_ceiling.py --scene all --reps 7 --launches 3   (each scene in its own
    process, --launches times; the ratio reported as its range)
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from numba import njit, uint64

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_common as bc  # noqa: E402

from hpcmpm.materials.decompositions import polar3  # noqa: E402


@njit(cache=True, inline="always")
def _weights(X):
    """Quadratic B-spline base node (unsigned) and the three weights at grid coordinate X."""
    b = int(X - 0.5)
    f = X - b
    return uint64(b), f, 0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2


@njit(cache=True, inline="always")
def _pick(i, a, b, c):
    return a if i == 0 else (b if i == 1 else c)


@njit(cache=True)
def step_2d(x, v, C, J, F, grid, fluid, n_grid, dt, p_vol, p_mass, E, mu, lam, gravity,
            bound):
    """One MLS-MPM step in 2D. x, v (n, 2); C, F (n, 2, 2); J (n,); grid (ng, ng, 3) holds
    momentum x, y and mass (then velocity x, y). fluid: tau = E (J - 1) I (mpm88), else fixed
    corotated on F."""
    dx = 1.0 / n_grid
    inv_dx = float(n_grid)
    k = -dt * p_vol * 4.0 * inv_dx * inv_dx
    g = grid.reshape(-1)
    for q in range(g.shape[0]):
        g[q] = 0.0
    for p in range(x.shape[0]):
        b0, f0, wx0, wx1, wx2 = _weights(x[p, 0] * inv_dx)
        b1, f1, wy0, wy1, wy2 = _weights(x[p, 1] * inv_dx)
        if fluid:
            s = k * E * (J[p] - 1.0)
            t00, t01, t10, t11 = s, 0.0, 0.0, s
        else:
            a, b, c, d = F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1]
            # R = [[cs, -sn], [sn, cs]] with (cs, sn) along (a + d, c - b): the closed-form 2D
            # polar rotation.
            r = math.sqrt((a + d) ** 2 + (c - b) ** 2)
            cs, sn = (a + d) / r, (c - b) / r
            m00, m01, m10, m11 = 2 * mu * (a - cs), 2 * mu * (b + sn), 2 * mu * (c - sn), \
                2 * mu * (d - cs)
            Jf = a * d - b * c
            pr = lam * Jf * (Jf - 1.0)
            t00 = k * (m00 * a + m01 * b + pr)
            t01 = k * (m00 * c + m01 * d)
            t10 = k * (m10 * a + m11 * b)
            t11 = k * (m10 * c + m11 * d + pr)
        a00, a01 = t00 + p_mass * C[p, 0, 0], t01 + p_mass * C[p, 0, 1]
        a10, a11 = t10 + p_mass * C[p, 1, 0], t11 + p_mass * C[p, 1, 1]
        mv0, mv1 = p_mass * v[p, 0], p_mass * v[p, 1]
        for i in range(uint64(3)):
            d0 = (i - f0) * dx
            wi = _pick(i, wx0, wx1, wx2)
            for j in range(uint64(3)):
                d1 = (j - f1) * dx
                w = wi * _pick(j, wy0, wy1, wy2)
                grid[b0 + i, b1 + j, 0] += w * (mv0 + a00 * d0 + a01 * d1)
                grid[b0 + i, b1 + j, 1] += w * (mv1 + a10 * d0 + a11 * d1)
                grid[b0 + i, b1 + j, 2] += w * p_mass
    for i in range(n_grid):
        for j in range(n_grid):
            m = grid[i, j, 2]
            if m > 0.0:
                u0 = grid[i, j, 0] / m
                u1 = grid[i, j, 1] / m - dt * gravity
                if (i < bound and u0 < 0.0) or (i > n_grid - bound and u0 > 0.0):
                    u0 = 0.0
                if (j < bound and u1 < 0.0) or (j > n_grid - bound and u1 > 0.0):
                    u1 = 0.0
                grid[i, j, 0] = u0
                grid[i, j, 1] = u1
    s4 = 4.0 * inv_dx * inv_dx
    for p in range(x.shape[0]):
        b0, f0, wx0, wx1, wx2 = _weights(x[p, 0] * inv_dx)
        b1, f1, wy0, wy1, wy2 = _weights(x[p, 1] * inv_dx)
        u0 = u1 = c00 = c01 = c10 = c11 = 0.0
        for i in range(uint64(3)):
            d0 = (i - f0) * dx
            wi = _pick(i, wx0, wx1, wx2)
            for j in range(uint64(3)):
                d1 = (j - f1) * dx
                w = wi * _pick(j, wy0, wy1, wy2)
                g0, g1 = w * grid[b0 + i, b1 + j, 0], w * grid[b0 + i, b1 + j, 1]
                u0 += g0
                u1 += g1
                c00 += g0 * d0
                c01 += g0 * d1
                c10 += g1 * d0
                c11 += g1 * d1
        c00, c01, c10, c11 = s4 * c00, s4 * c01, s4 * c10, s4 * c11
        v[p, 0], v[p, 1] = u0, u1
        x[p, 0] += dt * u0
        x[p, 1] += dt * u1
        C[p, 0, 0], C[p, 0, 1], C[p, 1, 0], C[p, 1, 1] = c00, c01, c10, c11
        if fluid:
            J[p] *= 1.0 + dt * (c00 + c11)
        else:
            a, b, c, d = F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1]
            F[p, 0, 0] = a + dt * (c00 * a + c01 * c)
            F[p, 0, 1] = b + dt * (c00 * b + c01 * d)
            F[p, 1, 0] = c + dt * (c10 * a + c11 * c)
            F[p, 1, 1] = d + dt * (c10 * b + c11 * d)


@njit(cache=True)
def step_3d(x, v, C, J, F, grid, fluid, n_grid, dt, p_vol, p_mass, E, mu, lam, gravity,
            bound):
    """One MLS-MPM step in 3D; see `step_2d`. grid (ng, ng, ng, 4)."""
    dx = 1.0 / n_grid
    inv_dx = float(n_grid)
    k = -dt * p_vol * 4.0 * inv_dx * inv_dx
    g = grid.reshape(-1)
    for q in range(g.shape[0]):
        g[q] = 0.0
    for p in range(x.shape[0]):
        b0, f0, wx0, wx1, wx2 = _weights(x[p, 0] * inv_dx)
        b1, f1, wy0, wy1, wy2 = _weights(x[p, 1] * inv_dx)
        b2, f2, wz0, wz1, wz2 = _weights(x[p, 2] * inv_dx)
        if fluid:
            s = k * E * (J[p] - 1.0)
            t00, t01, t02, t10, t11, t12, t20, t21, t22 = s, 0.0, 0.0, 0.0, s, 0.0, 0.0, 0.0, s
        else:
            f = (F[p, 0, 0], F[p, 0, 1], F[p, 0, 2], F[p, 1, 0], F[p, 1, 1], F[p, 1, 2],
                 F[p, 2, 0], F[p, 2, 1], F[p, 2, 2])
            R, _ = polar3(f)
            Jf = (f[0] * (f[4] * f[8] - f[5] * f[7]) - f[1] * (f[3] * f[8] - f[5] * f[6])
                  + f[2] * (f[3] * f[7] - f[4] * f[6]))
            pr = lam * Jf * (Jf - 1.0)
            m0, m1, m2 = 2 * mu * (f[0] - R[0]), 2 * mu * (f[1] - R[1]), 2 * mu * (f[2] - R[2])
            m3, m4, m5 = 2 * mu * (f[3] - R[3]), 2 * mu * (f[4] - R[4]), 2 * mu * (f[5] - R[5])
            m6, m7, m8 = 2 * mu * (f[6] - R[6]), 2 * mu * (f[7] - R[7]), 2 * mu * (f[8] - R[8])
            # tau = M F^T + pr I
            t00 = k * (m0 * f[0] + m1 * f[1] + m2 * f[2] + pr)
            t01 = k * (m0 * f[3] + m1 * f[4] + m2 * f[5])
            t02 = k * (m0 * f[6] + m1 * f[7] + m2 * f[8])
            t10 = k * (m3 * f[0] + m4 * f[1] + m5 * f[2])
            t11 = k * (m3 * f[3] + m4 * f[4] + m5 * f[5] + pr)
            t12 = k * (m3 * f[6] + m4 * f[7] + m5 * f[8])
            t20 = k * (m6 * f[0] + m7 * f[1] + m8 * f[2])
            t21 = k * (m6 * f[3] + m7 * f[4] + m8 * f[5])
            t22 = k * (m6 * f[6] + m7 * f[7] + m8 * f[8] + pr)
        a00, a01, a02 = t00 + p_mass * C[p, 0, 0], t01 + p_mass * C[p, 0, 1], t02 + p_mass * C[p, 0, 2]
        a10, a11, a12 = t10 + p_mass * C[p, 1, 0], t11 + p_mass * C[p, 1, 1], t12 + p_mass * C[p, 1, 2]
        a20, a21, a22 = t20 + p_mass * C[p, 2, 0], t21 + p_mass * C[p, 2, 1], t22 + p_mass * C[p, 2, 2]
        mv0, mv1, mv2 = p_mass * v[p, 0], p_mass * v[p, 1], p_mass * v[p, 2]
        for i in range(uint64(3)):
            d0 = (i - f0) * dx
            wi = _pick(i, wx0, wx1, wx2)
            for j in range(uint64(3)):
                d1 = (j - f1) * dx
                wij = wi * _pick(j, wy0, wy1, wy2)
                for kk in range(uint64(3)):
                    d2 = (kk - f2) * dx
                    w = wij * _pick(kk, wz0, wz1, wz2)
                    n0, n1, n2 = b0 + i, b1 + j, b2 + kk
                    grid[n0, n1, n2, 0] += w * (mv0 + a00 * d0 + a01 * d1 + a02 * d2)
                    grid[n0, n1, n2, 1] += w * (mv1 + a10 * d0 + a11 * d1 + a12 * d2)
                    grid[n0, n1, n2, 2] += w * (mv2 + a20 * d0 + a21 * d1 + a22 * d2)
                    grid[n0, n1, n2, 3] += w * p_mass
    for i in range(n_grid):
        for j in range(n_grid):
            for kk in range(n_grid):
                m = grid[i, j, kk, 3]
                if m > 0.0:
                    u0 = grid[i, j, kk, 0] / m
                    u1 = grid[i, j, kk, 1] / m - dt * gravity
                    u2 = grid[i, j, kk, 2] / m
                    if (i < bound and u0 < 0.0) or (i > n_grid - bound and u0 > 0.0):
                        u0 = 0.0
                    if (j < bound and u1 < 0.0) or (j > n_grid - bound and u1 > 0.0):
                        u1 = 0.0
                    if (kk < bound and u2 < 0.0) or (kk > n_grid - bound and u2 > 0.0):
                        u2 = 0.0
                    grid[i, j, kk, 0] = u0
                    grid[i, j, kk, 1] = u1
                    grid[i, j, kk, 2] = u2
    s4 = 4.0 * inv_dx * inv_dx
    for p in range(x.shape[0]):
        b0, f0, wx0, wx1, wx2 = _weights(x[p, 0] * inv_dx)
        b1, f1, wy0, wy1, wy2 = _weights(x[p, 1] * inv_dx)
        b2, f2, wz0, wz1, wz2 = _weights(x[p, 2] * inv_dx)
        u0 = u1 = u2 = 0.0
        c00 = c01 = c02 = c10 = c11 = c12 = c20 = c21 = c22 = 0.0
        for i in range(uint64(3)):
            d0 = (i - f0) * dx
            wi = _pick(i, wx0, wx1, wx2)
            for j in range(uint64(3)):
                d1 = (j - f1) * dx
                wij = wi * _pick(j, wy0, wy1, wy2)
                for kk in range(uint64(3)):
                    d2 = (kk - f2) * dx
                    w = wij * _pick(kk, wz0, wz1, wz2)
                    n0, n1, n2 = b0 + i, b1 + j, b2 + kk
                    g0, g1, g2 = w * grid[n0, n1, n2, 0], w * grid[n0, n1, n2, 1], \
                        w * grid[n0, n1, n2, 2]
                    u0 += g0
                    u1 += g1
                    u2 += g2
                    c00 += g0 * d0
                    c01 += g0 * d1
                    c02 += g0 * d2
                    c10 += g1 * d0
                    c11 += g1 * d1
                    c12 += g1 * d2
                    c20 += g2 * d0
                    c21 += g2 * d1
                    c22 += g2 * d2
        c00, c01, c02 = s4 * c00, s4 * c01, s4 * c02
        c10, c11, c12 = s4 * c10, s4 * c11, s4 * c12
        c20, c21, c22 = s4 * c20, s4 * c21, s4 * c22
        v[p, 0], v[p, 1], v[p, 2] = u0, u1, u2
        x[p, 0] += dt * u0
        x[p, 1] += dt * u1
        x[p, 2] += dt * u2
        C[p, 0, 0], C[p, 0, 1], C[p, 0, 2] = c00, c01, c02
        C[p, 1, 0], C[p, 1, 1], C[p, 1, 2] = c10, c11, c12
        C[p, 2, 0], C[p, 2, 1], C[p, 2, 2] = c20, c21, c22
        if fluid:
            J[p] *= 1.0 + dt * (c00 + c11 + c22)
        else:
            for c in range(3):
                e0, e1, e2 = F[p, 0, c], F[p, 1, c], F[p, 2, c]
                F[p, 0, c] = e0 + dt * (c00 * e0 + c01 * e1 + c02 * e2)
                F[p, 1, c] = e1 + dt * (c10 * e0 + c11 * e1 + c12 * e2)
                F[p, 2, c] = e2 + dt * (c20 * e0 + c21 * e1 + c22 * e2)


class Ceiling:
    """State and step of the fused kernel for a `bench_common.BenchScene`."""

    def __init__(self, s: bc.BenchScene):
        self.s = s
        d, n = s.dim, s.n
        self.x = s.x0.copy()
        self.v = s.v0.copy()
        self.C = np.zeros((n, d, d))
        self.J = np.ones(n)
        self.F = np.zeros((n, d, d))
        for a in range(d):
            self.F[:, a, a] = 1.0
        self.grid = np.zeros((s.n_grid,) * d + (d + 1,))
        self.fluid = s.material == bc.FLUID
        E = float(s.params["E"])
        nu = float(s.params.get("nu", 0.0))
        self.mu, self.lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
        self.E = E
        self._step = step_2d if d == 2 else step_3d

    def step(self) -> None:
        s = self.s
        self._step(self.x, self.v, self.C, self.J, self.F, self.grid, self.fluid, s.n_grid,
                   s.dt, s.p_vol, s.p_mass, self.E, self.mu, self.lam, s.gravity, s.bound)

    def run(self, steps: int) -> None:
        for _ in range(steps):
            self.step()


def bench_scene(key: str, steps: int, reps: int, smoke: bool, warmup: int) -> dict:
    s = bc.make_scene(key, smoke)
    ceiling = Ceiling(s)
    sim = bc.build_hpcmpm(s)
    hp_run = lambda k: [sim.step(s.dt) for _ in range(k)]  # noqa: E731
    ceiling.run(warmup)
    hp_run(warmup)
    sim.timers.reset()
    t_ceil, t_hp = [], []
    for _ in range(reps):
        t_ceil.append(bc.timed(ceiling.run, steps))
        t_hp.append(bc.timed(hp_run, steps))
    ce, hp = bc.summarize(t_ceil, steps, s.n), bc.summarize(t_hp, steps, s.n)
    for name, arr in (("ceiling x", ceiling.x), ("hpcmpm x", sim.particles["x"])):
        if not np.all(np.isfinite(arr)):
            raise RuntimeError(f"scene {key}: {name} is not finite")
    return {"scene": key, "title": s.title, "particles": s.n, "grid": s.n_grid, "dt": s.dt,
            "ceiling": ce, "hpcmpm": hp,
            "hpcmpm_phases_ms_per_step": bc.phase_ms(sim.timers, steps * reps),
            "ratio_hpcmpm_over_ceiling_min": ce["ms_per_step_min"] / hp["ms_per_step_min"],
            "ratio_hpcmpm_over_ceiling_median": ce["ms_per_step_median"] / hp["ms_per_step_median"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="all", choices=["a", "a_fc", "b", "all"])
    ap.add_argument("--steps", type=int, default=None, help="steps per repetition")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--smoke", action="store_true", help="tiny scenes (tests)")
    ap.add_argument("--out", default=None, help="results folder (default bench_results/)")
    bc.add_launch_arguments(ap)
    args = ap.parse_args(argv)
    keys = ["a", "a_fc", "b"] if args.scene == "all" else [args.scene]
    if args.in_process:
        results = []
        for key in keys:
            steps = args.steps or (5 if args.smoke else (200 if key != "b" else 20))
            results.append(bench_scene(key, steps, args.reps, args.smoke, args.warmup))
        doc = {"machine": bc.machine_info(), "results": results}
    else:
        passthrough = ["--reps", str(args.reps), "--warmup", str(args.warmup)]
        passthrough += (["--steps", str(args.steps)] if args.steps else []) + \
            (["--smoke"] if args.smoke else [])
        doc = bc.run_launches(Path(__file__), args, keys, "ceiling.json", passthrough)
    results = doc["results"]
    bc.print_table(
        ["scene", "particles", "ceiling ms/step min", "med", "hpcmpm ms/step min", "med",
         "hpcmpm/ceiling"],
        [[r["scene"], r["particles"], r["ceiling"]["ms_per_step_min"],
          r["ceiling"]["ms_per_step_median"], r["hpcmpm"]["ms_per_step_min"],
          r["hpcmpm"]["ms_per_step_median"], r["ratio_hpcmpm_over_ceiling_min"]]
         for r in results])
    for r in results:
        if "launches" in r:
            print(f"{r['scene']}: hpcmpm/ceiling over separate launches: min "
                  f"{bc.range_text(r, 'ratio_hpcmpm_over_ceiling_min')}, median "
                  f"{bc.range_text(r, 'ratio_hpcmpm_over_ceiling_median')}")
        print(f"{r['scene']}: hpcmpm phases (ms/step): " + ", ".join(
            f"{k} {v:.3f}" for k, v in r["hpcmpm_phases_ms_per_step"].items()))
    path = bc.write_json("ceiling.json", doc, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

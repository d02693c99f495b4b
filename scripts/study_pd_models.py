#!/usr/bin/env python
"""Measurements of the 003 ch. 5 peridynamic models (hpcmpm/pd/bond_energy.py,
viscoelastic_lps.py) that the issue asks to report rather than assert.

(i)   bond_energy: effective elastic constants of the interior under small uniform strains
      (C11, C12 from the energy of a uniaxial and a biaxial strain of 1e-6), nu_eff =
      C12/(C11 + C12) along a lattice axis, and the input nu it replaces.
(ii)  bond_energy energy drift: a free 2D block (PD integration, 003 Alg. 2, symplectic Euler)
      vibrating in its first mode, total energy E = kinetic (of the mean of the two half-step
      velocities around x^n) + sum V_p W_p(x^n) over the run, at
      0.8x and 0.4x the Silling-Askari step; the same for the LPS (an exact gradient, so
      only the integrator's bounded O(dt) oscillation) as reference. Reported: drift =
      (mean E over the last 10 % - mean E over the first 10 %) / E_0 and the peak-to-peak
      oscillation / E_0.
(iii) viscoelastic_lps: steady simple shear of a 2D lattice (interior virial stress) for
      memory = "maxwell" (sigma / (mu_lattice tau gamma_dot)) and memory = "none"
      (eta_eff = sigma / gamma_dot against mu_lattice dt, for several dt).

    python scripts/study_pd_models.py            # full (about a minute on 2 cores)
    python scripts/study_pd_models.py --smoke    # tiny sizes (seconds)

Writes bench_results/study_pd_models.json.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from hpcmpm.pd.families import full_family_sum  # noqa: E402
from hpcmpm.pd.bond_energy import (BondEnergy, bond_energy_scale,
                                   time_step_micromodulus)
from hpcmpm.pd.families import find_families
from hpcmpm.pd.integrator import PDBody, PDPoints
from hpcmpm.pd.lps import LPS, lps_bond_forces
from hpcmpm.pd.moduli import equivalent_micromodulus
from hpcmpm.pd.viscoelastic_lps import ViscoelasticLPS

REPO = Path(__file__).resolve().parents[1]
DELTA = 3.015
LAM, MU = 3.0, 1.0


def lattice(dim, n):
    axes = np.meshgrid(*[np.arange(n, dtype=np.float64)] * dim, indexing="ij")
    x0 = np.stack([a.ravel() for a in axes], axis=1)
    return x0, np.arange(len(x0), dtype=np.int64)


def bond_energy_model(dim, psi_p=math.inf):
    beta = bond_energy_scale(dim, LAM, MU, full_family_sum(dim, 1.0, DELTA))
    c = time_step_micromodulus(dim, 1.0, DELTA, "constant", True, beta, LAM, MU)
    return BondEnergy(dim, LAM, MU, beta, psi_p, time_step_c=c)


def elastic_constants(dim, n):
    e = 1e-6
    x0, ids = lattice(dim, n)
    radius = DELTA + 0.5
    inner = np.all((x0 >= radius) & (x0 <= n - 1 - radius), axis=1)
    energies = []
    for stretch in ([1 + e] + [1.0] * (dim - 1), [1 + e, 1 + e] + [1.0] * (dim - 2)):
        fam = find_families(x0, ids, len(x0), 1.0, DELTA)
        pts = PDPoints(x0.copy(), x0 * np.array(stretch), np.ones(len(x0)), ids, len(x0),
                       fam.bonds)
        m = bond_energy_model(dim)
        m.setup(pts)
        m.update_state(pts)
        energies.append(m.energy_density(pts)[inner].mean())
    C11 = 2 * energies[0] / e ** 2
    C12 = energies[1] / e ** 2 - C11
    return {"dim": dim, "C11": C11, "C12": C12, "nu_eff": C12 / (C11 + C12),
            "nu_input": LAM / (2 * (LAM + MU)), "bulk_ratio":
            (C11 + (dim - 1) * C12) / (dim * (LAM + 2 * MU / dim))}


def energy_run(name, n, steps, safety):
    x0, ids = lattice(2, n)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    if name == "bond_energy":
        model = bond_energy_model(2)
    else:
        K = LAM + MU
        model = LPS(K, MU, time_step_c=equivalent_micromodulus(2, K, MU, DELTA))
    L = n - 1.0
    amp = 1e-3 * math.sqrt((LAM + 2 * MU))           # strain amplitude ~ 1e-3
    v = np.zeros_like(x0)
    v[:, 0] = amp * np.sin(math.pi * x0[:, 0] / L - math.pi / 2)
    body = PDBody(x0, np.ones(len(x0)), ids, 1.0, fam, model, velocity=v)
    dt = body.stable_dt(safety)
    energies = []
    n_pts = len(x0)
    for _ in range(steps):
        # Symplectic Euler is leapfrog with half-step velocities: E^n = W(x^n) + kinetic
        # energy of (v^{n-1/2} + v^{n+1/2})/2, with W from the state computed at x^n.
        v_old, x_n = body.v.copy(), body.pts.x[:n_pts].copy()
        body.step(dt)
        x_next = body.pts.x[:n_pts].copy()
        body.pts.x[:n_pts] = x_n
        W = model.energy_density(body.pts)
        body.pts.x[:n_pts] = x_next
        v_mid = 0.5 * (v_old + body.v)
        energies.append(0.5 * float(np.sum(body.mass[:, None] * v_mid * v_mid))
                        + float(np.sum(W * body.pts.vol[:n_pts])))
    E = np.array(energies)
    k = max(1, steps // 10)
    return {"model": name, "safety": safety, "steps": steps, "dt": dt,
            "drift": float((E[-k:].mean() - E[:k].mean()) / E[0]),
            "oscillation": float((E.max() - E.min()) / E[0]), "E0": float(E[0])}


def shear_points(n):
    x0, ids = lattice(2, n)
    fam = find_families(x0, ids, len(x0), 1.0, DELTA)
    return PDPoints(x0.copy(), x0.copy(), np.ones(len(x0)), ids, len(x0), fam.bonds)


def virial_xy(pts, pair, n):
    b = pts.bonds
    owner = np.repeat(np.arange(b.n), b.counts())
    Y = pts.x[b.slot] - pts.x[owner]
    s = np.zeros(b.n)
    np.add.at(s, owner, 0.5 * pair[:, 0] * Y[:, 1])
    r = 2 * (DELTA + 0.5)
    inner = np.all((pts.x0 >= r) & (pts.x0 <= n - 1 - r), axis=1)
    return s[inner].mean()


def lattice_mu(n):
    K = LAM + MU
    g = 1e-6
    pts = shear_points(n)
    pts.x[:, 0] += g * pts.x0[:, 1]
    lps = LPS(K, MU)
    lps.setup(pts)
    lps.update_state(pts)
    b = pts.bonds
    out = np.empty((b.n_bonds, 2))
    lps_bond_forces(pts.x, pts.x0, pts.vol, b.offsets, b.slot, b.status, b.weight,
                    pts.fields["m"], lps.theta, K, MU, pts.n_owned, out)
    return virial_xy(pts, out, n) / g


def steady_shear(n, memory, tau, dt, rate, steps):
    pts = shear_points(n)
    model = ViscoelasticLPS(LAM + MU, MU, tau, memory)
    model.setup(pts)
    model.dt = dt
    f = np.empty((pts.n_owned, 2))
    b = pts.bonds
    pairs = np.empty((b.n_bonds, 2))      # the last step's stored forces (either memory)
    for k in range(1, steps + 1):
        pts.x[:, 0] = pts.x0[:, 0] + rate * k * dt * pts.x0[:, 1]
        model.update_state(pts)
        model.forces(pts, f, pairs=pairs)
    owner = np.repeat(np.arange(b.n), b.counts())
    Y = pts.x[b.slot] - pts.x[owner]
    a = pairs.sum(axis=1)
    pair = (a / np.linalg.norm(Y, axis=1))[:, None] * Y
    return virial_xy(pts, pair, n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--out", default=str(REPO / "bench_results" / "study_pd_models.json"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    nshear = 18 if args.smoke else 20
    steps = 50 if args.smoke else 4000
    out = {"elastic_constants": [elastic_constants(2, 12 if args.smoke else 16)]
           + ([] if args.smoke else [elastic_constants(3, 12)])}
    out["energy"] = [energy_run(m, 12 if args.smoke else 24, steps, s)
                     for m in ("bond_energy", "lps") for s in ((0.8,) if args.smoke
                                                                else (0.8, 0.4))]
    mu_lat = lattice_mu(nshear)
    tau, rate = 1.0, 1e-4
    out["viscoelastic"] = {"mu_lattice_over_mu": mu_lat / MU, "maxwell": [], "none": []}
    for dt in ((0.1,) if args.smoke else (0.1, 0.05, 0.02)):
        s = steady_shear(nshear, "maxwell", tau, dt, rate, int(round(10 * tau / dt)))
        out["viscoelastic"]["maxwell"].append(
            {"dt": dt, "sigma_over_mu_tau_rate": s / (mu_lat * tau * rate)})
    for dt in ((0.02, 0.01) if args.smoke else (0.04, 0.02, 0.01, 0.005)):
        s = steady_shear(nshear, "none", math.inf, dt, 1e-3, 10)
        out["viscoelastic"]["none"].append(
            {"dt": dt, "eta_over_mu": s / 1e-3 / mu_lat, "eta_over_mu_dt": s / 1e-3 / mu_lat / dt})
    out["wall_s"] = time.perf_counter() - t0
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

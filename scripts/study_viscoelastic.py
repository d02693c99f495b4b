#!/usr/bin/env python
"""Homogeneous-driver study of the b_E models (issue 9): the numbers behind
tests/verification/test_viscoelastic_driver.py, and the stability limits in dt/Wi.

(i)   Oldroyd-B closed forms (start-up shear, relaxation, extension; W in {0.5, 1}, d in {2, 3},
      every plasticity): stress error at dt/Wi = 0.01 and the log-log slopes of the stress and
      conformation errors over dt/Wi = 0.04 ... 0.005 (definitions in the test module).
(ii)  Steady Herschel-Bulkley flow curve and von Mises plateau: relative errors.
(iii) Stability limit of each plastic update: the smallest dt/Wi (to 0.1 %) at which a run of
      3000 steps does not settle to a steady state (last step changes b by more than 1e-8
      relative, or |b| > 1000 |b0|, or an inadmissible state), for relaxation from the
      steady-shear conformation and start-up shear; the table gives the largest settled dt/Wi
      below it. ob_spd never loses definiteness; its "limit" at large W is the |b| bound (the
      discrete steady state of a shear with dt gdot >> 1 is large, i.e. inaccurate, not
      unstable).

    python scripts/study_viscoelastic.py            # everything (about a minute when cached)
    python scripts/study_viscoelastic.py --smoke    # one case of each part (seconds)

Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hpcmpm.materials import make_material  # noqa: E402
from hpcmpm.materials.driver import drive  # noqa: E402

# The closed forms live with the test that asserts them; load that module by path.
_spec = importlib.util.spec_from_file_location(
    "viscoelastic_reference", REPO / "tests/verification/test_viscoelastic_driver.py")
ref = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = ref  # dataclasses look their module up
_spec.loader.exec_module(ref)


def closed_forms(smoke: bool) -> None:
    print("| flow | plasticity | d | W | stress error at dt/Wi=0.01 | stress slope | "
          "conformation slope |")
    print("|---|---|---|---|---|---|---|")
    flows = ("startup_shear",) if smoke else ("startup_shear", "relaxation", "extension")
    for name in flows:
        for plasticity in ref.PLASTICITIES[:1] if smoke else ref.PLASTICITIES:
            for dim in (2,) if smoke else (2, 3):
                for W in ref.WEISSENBERGS:
                    e = np.array([ref.run(name, plasticity, dim, W, r) for r in ref.RATIOS])
                    print(f"| {name} | {plasticity} | {dim} | {W} | "
                          f"{e[ref.RATIOS.index(0.01), 0]:.2e} | {ref.slope(e[:, 0]):.3f} | "
                          f"{ref.slope(e[:, 1]):.3f} |")


def flow_curves(smoke: bool) -> None:
    print("\n| model | d | h | rate | tau_xy | expected | relative error |")
    print("|---|---|---|---|---|---|---|")
    for dim in (2,) if smoke else (2, 3):
        for h in (1.0,) if smoke else (0.5, 1.0, 2.0):
            for rate in (0.1, 1.0):
                mat = make_material(ref.Spec("herschel_bulkley", {
                    "mu": ref.MU, "lambda": ref.LAM, "yield_strain": 0.01,
                    "flow_consistency": 0.01, "flow_index": h}), dim)
                L = np.zeros((dim, dim))
                L[0, 1] = rate
                tau = drive(mat, lambda t: L, 1e-4 / rate, 5000).sigma()[-1, 0, 0, 1]
                ex = mat.flow_curve(rate)
                print(f"| herschel_bulkley | {dim} | {h} | {rate} | {tau:.6g} | {ex:.6g} | "
                      f"{(tau - ex) / ex:.2e} |")
        mat = make_material(ref.Spec("von_mises", {"mu": ref.MU, "lambda": ref.LAM,
                                                   "yield_strain": 0.01}), dim)
        L = np.zeros((dim, dim))
        L[0, 1] = 1.0
        tau = drive(mat, lambda t: L, 1e-4, 2000).sigma()[-1, 0, 0, 1]
        ex = mat.shear_yield_stress()
        print(f"| von_mises | {dim} | - | 1.0 | {tau:.6g} | {ex:.6g} | {(tau - ex) / ex:.2e} |")


def settles(name: str, plasticity: str, W: float, ratio: float, steps: int = 3000) -> bool:
    L, A0, _, _ = ref.flow(name, 2, W)
    mat = ref.oldroyd_b(2, plasticity, viscosity=0.0)
    state = {"b": A0}
    if "Fe" in mat.fields:
        state["Fe"] = np.linalg.cholesky(A0)
    try:
        res = drive(mat, lambda t: L, ratio * ref.WI, steps, state=state, record=("b",))
    except FloatingPointError:
        return False
    b = res.history["b"][:, 0]
    if not np.all(np.isfinite(b)):
        return False
    return bool(np.abs(b[-1] - b[-2]).max() <= 1e-8 * np.abs(b[-1]).max()
                and np.abs(b[-1]).max() < 1e3 * np.abs(A0).max())


def limit(name: str, plasticity: str, W: float, lo: float = 0.05, hi: float = 200.0) -> float:
    """The first instability: scan dt/Wi upwards from ``lo`` in 10 % steps to the first run
    that does not settle, then bisect (0.1 %) between it and the last one that did; inf when
    every run up to ``hi`` settles. Not a plain bisection over [lo, hi]: fe_bdf2 in shear has
    stable windows above its first instability (a period-2 oscillation at W = 1 from
    dt/Wi ~ 1.75, settled again at 5, unbounded from ~6.5)."""
    r = lo
    while settles(name, plasticity, W, r):
        if r >= hi:
            return math.inf
        r *= 1.1
    if r == lo:
        return 0.0
    good, bad = r / 1.1, r
    while bad - good > 1e-3 * good:
        mid = 0.5 * (good + bad)
        good, bad = (mid, bad) if settles(name, plasticity, W, mid) else (good, mid)
    return good


def stability(smoke: bool) -> None:
    print("\n| flow | plasticity | W | largest stable dt/Wi |")
    print("|---|---|---|---|")
    for name in ("relaxation",) if smoke else ("relaxation", "startup_shear"):
        for plasticity in ("fe_bdf2",) if smoke else ref.PLASTICITIES:
            for W in (1.0,) if smoke else (0.5, 1.0, 2.0, 5.0):
                print(f"| {name} | {plasticity} | {W} | {limit(name, plasticity, W):.4g} |",
                      flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="one case of each part")
    args = parser.parse_args()
    closed_forms(args.smoke)
    flow_curves(args.smoke)
    stability(args.smoke)


if __name__ == "__main__":
    main()

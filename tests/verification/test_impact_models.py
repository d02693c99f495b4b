"""Impact models against closed forms at material points (no grid): the Johnson-Cook curve
under uniaxial stress at a constant strain rate (003 §7.3, appendix B)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hpcmpm.materials import make_material
from hpcmpm.materials.driver import MaterialPoint
from hpcmpm.scene import MaterialSpec

# Wilkins & Guinan 1973 OFHC copper, Johnson & Cook 1983 constants (the Taylor bar).
RHO0, E_CU, NU_CU = 8960.0, 124e9, 0.34
A, B, N, C = 90e6, 292e6, 0.31, 0.025
JC_CU = {"type": "johnson_cook", "A": A, "B": B, "n": N, "C": C, "eps_dot0": 1.0}


def spec(type_: str, params: dict) -> MaterialSpec:
    return MaterialSpec("cu", type_, RHO0, params)


def uniaxial_stress(return_map: str, rate: float = 1e3, eps_end: float = 0.55,
                    steps: int = 2200) -> tuple[np.ndarray, np.ndarray]:
    """Drive one point with L = diag(rate, a, a), a chosen each step (secant iteration) so the
    lateral stress vanishes: uniaxial stress at a constant axial strain rate. Returns the
    equivalent plastic strain and the axial stress after each step."""
    mat = make_material(spec("j2", {"E": E_CU, "nu": NU_CU, "hardening": JC_CU,
                                    "return_map": return_map}), 3)
    mp = MaterialPoint(mat, 1, dx=1.0)
    dt = eps_end / rate / steps
    a = -NU_CU * rate
    eps_p, sigma = np.empty(steps), np.empty(steps)
    for k in range(steps):
        saved = {name: f.copy() for name, f in mp.fields.items()}

        def lateral(a_trial: float) -> float:
            for name, f in mp.fields.items():
                f[:] = saved[name]
            mp.step(np.diag([rate, a_trial, a_trial]), dt)
            return mp.cauchy()[0, 1, 1]

        a0, a1 = a, a * (1 + 1e-3)
        r0, r1 = lateral(a0), lateral(a1)
        for _ in range(30):
            if r1 == r0:
                break
            a0, a1, r0 = a1, a1 - r1 * (a1 - a0) / (r1 - r0), r1
            r1 = lateral(a1)
            if abs(r1) <= 1e-12 * max(abs(mp.cauchy()[0, 0, 0]), 1.0):
                break
        a = a1
        sig = mp.cauchy()[0]
        assert abs(sig[1, 1]) <= 1e-9 * abs(sig[0, 0]) + 1.0  # uniaxial to 1 Pa
        eps_p[k], sigma[k] = mp.fields["eps_p"][0], sig[0, 0]
    return eps_p, sigma


def curve_error(eps_p: np.ndarray, sigma: np.ndarray, rate: float = 1e3) -> float:
    """max |sigma / JC(eps_p, rate) - 1| over eps_p in [0.01, 0.5]."""
    window = (eps_p >= 0.01) & (eps_p <= 0.5)
    assert window.sum() > 20
    jc = (A + B * eps_p[window] ** N) * (1 + C * math.log(rate))
    return float(np.abs(sigma[window] / jc - 1).max())


@pytest.fixture(scope="module")
def errors():
    """Curve errors of both return maps at 2200 and 220 steps (strain increments 2.5e-4 and
    2.5e-3 per step; the yield strain A/E is 7.3e-4)."""
    return {(m, steps): curve_error(*uniaxial_stress(m, steps=steps))
            for m in ("newton", "linearized") for steps in (2200, 220)}


def test_johnson_cook_curve_under_uniaxial_stress(errors):
    """sigma_xx follows (A + B eps_p^n)(1 + C ln eps_dot*) within 0.5 % for eps_p in
    [0.01, 0.5] at eps_dot = 1e3/s with the exact (Newton) return, at either step size. What
    remains is physics, not the return: the plastic rate is eps_dot/(1 + H/E), below the
    applied rate while the hardening modulus H is not negligible against E (measured: -4.3e-4
    relative, the largest at eps_p = 0.01)."""
    for steps in (2200, 220):
        error = errors["newton", steps]
        print(f"JC curve, Newton return, {steps} steps: max relative error {error:.3e}")
        assert error <= 5e-3
    # The exact return does not depend on the step: the two runs differ by the rate effect's
    # sampling only (measured 1.3e-5).
    assert abs(errors["newton", 2200] - errors["newton", 220]) <= 1e-4


def test_linearized_return_error_is_reported(errors):
    """B.5's single linearized step (E^p of eq. 7.8 at the start of the step) lags the curve
    where JC is most curved, by an error that grows with the strain increment (measured:
    2.1e-5 at 2200 steps, 3.1e-3 at 220, 1.1e-2 at 110); at the coarse step it is worse than
    the exact return."""
    for steps in (2200, 220):
        print(f"JC curve, linearized return (003 B.5), {steps} steps: max relative error "
              f"{errors['linearized', steps]:.3e}")
    assert errors["linearized", 220] > 3 * errors["linearized", 2200]
    assert errors["linearized", 220] > errors["newton", 220]

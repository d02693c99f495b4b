"""Load-balance cost of peridynamic particles (issue 10: "load balance weighs particles by
their active bonds, cost per half-bond measured").

A PD particle costs ``1 + c_b * b`` MPM particles per step, b its active half-bonds
(`Simulation.load_weights`, `Domain.decompose` / `rebalance`). c_b per dimension and model,
measured with scripts/measure_pd_bond_cost.py: CPU time (`time.process_time`) of 40 steps of
the same block as an MPM body (neo-Hookean, APIC, quadratic) and as an off-grid PD body,
after 3 warm-up steps, the least of 5 runs (the minimum is the run least disturbed by the
other processes of a shared machine), c_b = (t_PD / t_MPM - 1) / b. The table holds the
median of 3 launches on an AMD EPYC host, 2 vCPUs, one numba thread (2026-12-06, after the
one-division force loops of that week), ranges in brackets:

    2D (6400 particles, 34.7 half-bonds each, MPM 114-123 ns per particle-step):
        pmb 0.061 [0.061-0.080], lps 0.136 [0.131-0.139], correspondence 0.510 [0.482-0.546]
    3D (13824 particles, 150.8 half-bonds each, MPM 490-582 ns per particle-step):
        pmb 0.0122 [0.0116-0.0134], lps 0.028 [0.025-0.033], correspondence 0.138 [0.118-0.138]

(PMB kept at its first measurement, which lies in this host's range.) The host moves c_b
as much as the code does: the table's first version (Intel Xeon, 2026-11-30) had 2D
correspondence 0.338, and that same commit measured 0.54-0.57 here; 2D LPS was 0.21-0.23
here at that commit (0.158 on the Xeon), 0.13-0.14 after its force loop came to divide once
a bond. So a c_b is good to tens of per cent on another machine. A 3D MPM particle costs
about 4x a 2D one (27 nodes against 9), while a half-bond costs about the same (8-10 ns for
PMB).
The PD step includes its halo refreshes and the full halo rebuild after each sort. A model
not in the table (another module's) is weighed as the LPS of its dimension (a two-pass
model).
"""

from __future__ import annotations

import numpy as np

from ..state import SCALAR, FieldSpec

# Active (intact) half-bonds of a particle, its load-balance weight (`add_bond_load`); -1
# until its bonds are made. One spec for PD materials and SPB materials
# (materials/peridynamic.py, materials/failure.py): a scene with both shares the field.
ACTIVE_BONDS = FieldSpec(SCALAR, "i4", -1)

BOND_COST = {(2, "pmb"): 0.061, (2, "lps"): 0.136, (2, "correspondence"): 0.510,
             (3, "pmb"): 0.0122, (3, "lps"): 0.028, (3, "correspondence"): 0.138}


def bond_cost(dim: int, model: str) -> float:
    """c_b: the cost of one active half-bond per step, in MPM particle-steps."""
    return BOND_COST.get((dim, model), BOND_COST[(dim, "lps")])


def add_bond_load(weights: np.ndarray, rows: np.ndarray, active_bonds: np.ndarray,
                  unit: int, c_b: float, family: int) -> None:
    """weights[rows] += round(unit c_b b), b = ``active_bonds`` (the particles' field
    "active_bonds", the intact half-bonds counted from their bond rows; a particle field, so
    the weight travels with the particle and is the same on every rank count); -1 (bonds
    not made yet, or a checkpoint written before the field existed) weighs an interior
    family of ``family`` half-bonds."""
    active = active_bonds.astype(np.float64)
    active[active < 0] = family
    weights[rows] += np.rint(unit * c_b * active).astype(np.int64)

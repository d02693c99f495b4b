"""The ``failure`` table of a material: SPB-MPM (003 ch. 6), MPM particles that become
peridynamic where the grid energy exceeds a threshold.

    [[materials]]
    type = "fixed_corotated"  ...
    failure = { model = "spb", grid_energy = 2.0e3, bond_energy = 1.5 }

Keys (`SPB_SCHEMA`): ``grid_energy`` G_EE (> 0; a node is flagged when G_i >= G_EE, eq. 6.10),
``bond_energy`` G_c (> 0, inf: bonds never break by energy; eq. 6.12), ``energy``
("stress_squared" as printed, or "tensile_energy"), ``coupling`` ("exclusive": PD particles
scatter mass and momentum but no stress, the default chosen by the patch test; "additive": the
PD force on top of the MPM stress, as Alg. 3 prints), ``bond_failure`` ("energy" eq. 6.11 as
printed, "work" the accumulated work, "stretch" eq. 4.8 with ``critical_stretch``),
``influence`` ("constant" omega = 1, or "linear" omega = |X|/delta as eq. 6.13 prints),
``horizon`` (delta in particle spacings, default 3.015), ``stabilization`` (Silling 2017 zero-energy-mode control, times the PMB micromodulus),
``max_bond_stretch`` (every bond breaks beyond it; sets the PD halo reach), ``clamp``
("sticky_walls": a PD particle within a horizon of a sticky domain wall is bonded to the
mirror image of its family, a clamped end, hpcmpm/pd/clamp.py; "none": the wall holds PD
particles only through the grid).

A material takes part when its class lists ``"failure": SPB_FAILURE`` in ``parameters`` and can
give a stress for peridynamics at a deformation gradient F^PD (`pd_stress`): the elastic models,
snow (F_E = F^PD F_P^-1) and the impact models of deformation mode "L" (`shock`, `j2`: their own
stress from their own state, 003 §7.2.2 "reuse the MPM pressure"; they carry no total F). Any
other material with a ``failure`` table is a one-line scene error (`no_pd_stress_problem`);
combinations SPB-MPM cannot run are listed by `failure_scene_problems`.
"""

from __future__ import annotations

import math

import numpy as np

from ..state import SCALAR, VECTOR, FieldSpec
from ..pd.families import horizon_problem
from ..pd.load import ACTIVE_BONDS
from .params import Param, choice, table

COUPLINGS = ("exclusive", "additive")
DEFAULT_COUPLING = "exclusive"   # the patch test (tests/verification/test_spb_coupled.py)

SPB_SCHEMA = {
    "model": choice(("spb",), doc="failure model: 'spb' (003 ch. 6)"),
    "grid_energy": Param(0.0, math.inf, doc="G_EE: grid energy release that converts a cell "
                                             "to peridynamics (eq. 6.10), > 0"),
    "bond_energy": Param(0.0, math.inf, high_inclusive=True,
                         doc="G_c: energy release rate of the bonds (eq. 6.12); inf: none"),
    "energy": choice(("stress_squared", "tensile_energy"), "stress_squared",
                     doc="Phi of eq. 6.10: sigma+:sigma+ or the tensile strain energy"),
    "coupling": choice(COUPLINGS, DEFAULT_COUPLING,
                       doc="exclusive: PD particles carry no MPM stress; additive: Alg. 3"),
    "bond_failure": choice(("energy", "work", "stretch"), "energy",
                           doc="eq. 6.11 as printed, accumulated work, or eq. 4.8"),
    "critical_stretch": Param(0.0, math.inf, required=False, default=None,
                              doc="s0 of eq. 4.8 (bond_failure = 'stretch')"),
    "influence": choice(("constant", "linear"), "constant",
                        doc="omega(|X|): 1, or |X|/delta (eq. 6.13 as printed)"),
    "horizon": Param(1.0, math.inf, required=False, default=3.015, low_inclusive=True,
                     doc="delta in particle spacings"),
    "stabilization": Param(0.0, math.inf, required=False, default=0.1, low_inclusive=True,
                           doc="zero-energy-mode penalty, times the PMB micromodulus"),
    "max_bond_stretch": Param(0.0, math.inf, required=False, default=1.0,
                              doc="bonds stretched beyond it break (sets the halo reach)"),
    "clamp": choice(("sticky_walls", "none"), "sticky_walls",
                    doc="sticky_walls: PD particles near a sticky domain wall get the mirror "
                        "bonds of a clamped end (hpcmpm/pd/clamp.py); none: the grid only"),
}
SPB_FAILURE = table(SPB_SCHEMA, doc="SPB-MPM failure (003 ch. 6)")

# Particle fields of an SPB material: reference positions (NaN until the first step sets
# them), the energy history EE_p, the model (0 MPM, 1 PD), the damage phi and the active
# half-bonds of a PD particle (its load-balance weight; written with the damage, so it
# travels with the particle; -1, the PD materials' spec, on MPM particles, which
# `SPBExtension.add_load` does not read).
SPB_FIELDS = {
    "x0": FieldSpec(VECTOR, "f8", math.nan),
    "EE": FieldSpec(SCALAR, "f8", 0.0),
    "model": FieldSpec(SCALAR, "i1", 0),
    "damage": FieldSpec(SCALAR, "f8", 0.0),
    "active_bonds": ACTIVE_BONDS,
}


def no_pd_stress_problem(type_name: str) -> str:
    return (f"failure: material type {type_name!r} has no stress for peridynamics "
            f"(SPB-MPM needs an elastic model, snow, shock or j2)")


# Keys every SPB material of a scene must agree on: one extension, one bond set.
SHARED_KEYS = ("coupling", "bond_failure", "critical_stretch", "influence", "horizon",
               "max_bond_stretch", "clamp")


def failure_scene_problems(materials, transfer: str, integrator: str, periods=(),
                           spacing: float | None = None) -> list[tuple[str, str]]:
    """(key path, what is wrong) for each combination SPB-MPM cannot run, given the
    material instances of a scene: MLS transfer (the re-transfer recomputes C as the
    velocity gradient), the explicit integrator (Alg. 3 is an explicit step), a Young's
    modulus where eq. 6.10's tensile energy divides by it, the keys the SPB materials
    share, and (``periods``: (axis, period) of the periodic axes; ``spacing``: the particle
    spacing) a family radius that reaches half a period: a converted particle's family
    would then hold two images of one partner, which the conversions' bond search does not
    build (pd/spb.py; a peridynamic material's families do). Deformation modes "F" and "L"
    both work: in mode "L" the re-transfer corrects the stored L before the materials'
    state update, and eq. 6.10 divides tau by the material's own volume ratio J where it
    carries no F (`shock`, `j2`)."""
    groups = [g for g, m in enumerate(materials) if getattr(m, "failure", None)]
    if not groups:
        return []
    first = f"materials[{groups[0]}].failure"
    problems = []
    if transfer != "mls":
        problems.append((first, f"SPB-MPM needs simulation.transfer = 'mls' (the re-transfer "
                                f"recomputes C as the velocity gradient), got {transfer!r}"))
    if integrator != "explicit":
        problems.append((first, f"SPB-MPM needs simulation.integrator = 'explicit' (003 "
                                f"Alg. 3 is an explicit step), got {integrator!r}"))
    for g in groups:
        m = materials[g]
        if m.failure["energy"] == "tensile_energy" and not m.params.get("E", 0.0) > 0.0:
            problems.append((f"materials[{g}].failure.energy",
                             "'tensile_energy' divides by Young's modulus: needs E > 0"))
    specs = [materials[g].failure for g in groups]
    names = [materials[g].spec.name for g in groups]
    too_wide = [(f"materials[{g}].failure.horizon", line) for g, spec in zip(groups, specs)
                if (line := horizon_problem(materials[g].dim, spec["horizon"]))]
    if too_wide:  # the checks below and the time step would build lattices of its size
        return problems + too_wide
    for key in SHARED_KEYS:
        values = {repr(s[key]) for s in specs}
        if len(values) > 1:
            problems.append((f"{first}.{key}", f"SPB materials "
                                               f"{', '.join(map(repr, names))} must agree, "
                                               f"got {', '.join(sorted(values))}"))
    if spacing:
        from ..pd.families import family_radius

        radius = family_radius(specs[0]["horizon"] * spacing, spacing, True)
        for axis, period in periods:
            if 2.0 * radius >= period:
                name = "xyz"[axis]
                problems.append((f"{first}.horizon", f"the family radius {radius:g} reaches "
                                 f"half the period {period:g} of the periodic axis {name}: a "
                                 f"converted particle would bond to two images of one "
                                 f"partner, which SPB-MPM does not build (the domain must be "
                                 f"wider than {2.0 * radius:g} along {name}, or the horizon "
                                 f"shorter)"))
    return problems


def pd_moduli(dim: int, material) -> tuple[float, float]:
    """(bulk, shear) modulus of a material for its peridynamic micromoduli (stabilization and
    PD time step): from E and nu, or, for a model with a volumetric response of its own (an
    EOS: `shock`, `j2`), dp/dzeta at rest (rho0 c0^2, or K) and its shear modulus."""
    from ..pd.moduli import bulk_modulus, shear_modulus

    vol = getattr(material, "volumetric_response", None)
    if vol is not None:
        return float(vol.K), float(material.mu)
    E, nu = material.params["E"], material.params["nu"]
    return bulk_modulus(dim, E, nu), shear_modulus(E, nu)


def attach_failure(material) -> None:
    """Called by Material.__init__: an SPB material declares its extra fields and the step
    extension that converts and evolves its PD particles (hpcmpm/pd/spb.py)."""
    spec = material.params.get("failure") if "failure" in material.parameters else None
    material.failure = spec
    if spec is None:
        return
    problems = []
    if spec["bond_failure"] == "stretch" and spec["critical_stretch"] is None:
        problems.append("failure.critical_stretch: missing (bond_failure = 'stretch')")
    if problems:
        from ..errors import SceneError

        raise SceneError([f"material {material.spec.name!r} ({material.name}): {p}"
                          for p in problems])
    material.fields = {**type(material).fields, **SPB_FIELDS}
    material.make_extension = _make_extension


def _make_extension(sim):
    """The scene's one SPB extension (shared by all its SPB materials), or None when
    another SPB material already made it."""
    from ..pd.spb import SPBExtension

    if any(isinstance(e, SPBExtension) for e in sim.extensions):
        return None
    return SPBExtension(sim)


def pd_stress(material, fields: dict, F: np.ndarray, tau: np.ndarray) -> None:
    """Kirchhoff stress tau (k, d, d) of ``material`` at the PD deformation gradients F
    (k, d, d) of particles whose fields (rows gathered into ``fields``) hold the rest of
    their state (003 Alg. 3 line 15 as corrected: sigma^PD from the particle's own material).
    Each model gives it as ``material.pd_stress(fields, F, tau)``: the elastic models their
    stress of F (`ElasticMaterial.pd_stress`), snow its elastic part F_E = F^PD F_P^-1 with
    its hardening (`Snow.pd_stress`), the impact models their own (`ImpactMaterial`)."""
    if not hasattr(material, "pd_stress"):
        raise TypeError(no_pd_stress_problem(material.name))
    material.pd_stress(fields, F, tau)

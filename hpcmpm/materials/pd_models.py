"""Scene keys and model construction of the 003 ch. 5 peridynamic models, for the material
``type = "peridynamic"`` (peridynamic.py): ``model = "bond_energy"`` (eq. 5.5-5.6, with bond
plasticity eq. 5.8-5.11: ``plastic_yield`` or ``plastic_yield_stretch``),
``model = "viscoelastic_lps"`` (eq. 5.12-5.20: ``relaxation_time``, ``memory``) and crack
planes (003 §5.4: ``crack_threshold``, ``two_time_integration``). The physics is in
hpcmpm/pd/bond_energy.py, viscoelastic_lps.py and crack_planes.py; this module only reads the
keys (kept apart from peridynamic.py so that file needs only hook lines)."""

from __future__ import annotations

import math

from ..errors import SceneError
from .params import Param, choice


def _is_bool(value):
    return None if isinstance(value, bool) else f"must be true or false, got {value!r}"


EXTRA_PARAMETERS = {
    "plastic_yield": Param(0.0, math.inf, False, math.inf, high_inclusive=True,
                           doc="bond_energy: psi_p of the bond yield function (003 eq. 5.10); "
                               "inf: elastic"),
    "plastic_yield_stretch": Param(0.0, math.inf, False, math.inf, high_inclusive=True,
                                   doc="bond_energy: the deviatoric stretch at which a bond "
                                       "of length delta and unit influence yields (sets "
                                       "psi_p at any dx); inf: elastic"),
    "relaxation_time": Param(0.0, math.inf, False, math.inf, high_inclusive=True,
                             doc="viscoelastic_lps: Maxwell time tau of the deviatoric part; "
                                 "inf: elastic"),
    "memory": choice(("maxwell", "none"), "maxwell",
                     "viscoelastic_lps: stored bond forces (maxwell) or eq. 5.14 literally "
                     "(none: force = last increment, a viscosity ~ dt)"),
    "crack_threshold": Param(0.0, math.inf, False, None,
                             doc="l_threshold of 003 §5.4 crack planes (replaces the critical "
                                 "stretch test)"),
    "two_time_integration": Param(-math.inf, math.inf, False, True, check=_is_bool,
                                  doc="crack planes on the grid: particles with a broken bond "
                                      "move by their own PD force"),
}

# Keys that only mean something for one model: set for another, they are an error, not
# silently ignored.
_ONLY = {"plastic_yield": ("bond_energy",), "plastic_yield_stretch": ("bond_energy",),
         "relaxation_time": ("viscoelastic_lps",), "memory": ("viscoelastic_lps",)}


def check_chapter5(prm: dict, where: str) -> None:
    """SceneError for a ch. 5 key given to a model that does not use it."""
    for key, models in _ONLY.items():
        default = EXTRA_PARAMETERS[key].default
        if prm[key] != default and prm["model"] not in models:
            raise SceneError(f"{where}: {key}: only for model = {' or '.join(models)} "
                             f"(got model = {prm['model']!r})")
    if prm["plastic_yield"] < math.inf and prm["plastic_yield_stretch"] < math.inf:
        raise SceneError(f"{where}: plastic_yield_stretch: sets the same yield as "
                         "plastic_yield (psi_p); give one of them (an override replacing "
                         "one sets the other to inf)")
    if prm["crack_threshold"] is not None and prm["fracture_energy"] is not None:
        raise SceneError(f"{where}: crack_threshold: crack planes replace the stretch "
                         "criterion; remove fracture_energy")


def has_bond_plasticity(prm: dict) -> bool:
    """Whether a bond-energy body yields (either yield key set)."""
    return prm["plastic_yield"] < math.inf or prm["plastic_yield_stretch"] < math.inf


def bond_yield_energy(material, beta: float) -> float:
    """psi_p of eq. 5.10 for ``model = "bond_energy"``: ``plastic_yield`` as given, or the
    one ``plastic_yield_stretch`` names at this material's horizon with its scale ``beta``
    (`_bond_energy_scale`; bond_energy.yield_energy_of_stretch); inf without plasticity."""
    prm = material.params
    if prm["plastic_yield_stretch"] == math.inf:
        return prm["plastic_yield"]
    from ..pd.bond_energy import yield_energy_of_stretch

    return yield_energy_of_stretch(beta, material.lam, material.mu, material.delta,
                                   prm["plastic_yield_stretch"])


def bond_yield_description(material) -> str | None:
    """One line naming a bond-energy body's psi_p and the yield stretch s_y it amounts to at
    this material's spacing (psi_p's unit depends on the horizon, a stretch's does not), or
    None without bond plasticity. For the run log and ``hpcmpm validate``."""
    prm = material.params
    if prm["model"] != "bond_energy" or not has_bond_plasticity(prm):
        return None
    from ..pd.bond_energy import yield_stretch_of_energy

    beta, _ = _bond_energy_scale(material)
    psi_p = bond_yield_energy(material, beta)
    s_y = yield_stretch_of_energy(beta, material.lam, material.mu, material.delta, psi_p)
    return (f"material {material.spec.name!r}: bond plasticity psi_p = {psi_p:.6g}, the yield "
            f"stretch s_y = {s_y:.6g} of a bond of length delta = {material.delta:.6g} with "
            f"unit influence (plastic_yield_stretch)")


def _bond_energy_scale(material) -> tuple[float, tuple]:
    from ..pd.bond_energy import bond_energy_scale
    from ..pd.families import full_family_sum

    prm = material.params
    args = (material.dim, material.spacing, material.delta, prm["influence"],
            prm["partial_volumes"])
    return bond_energy_scale(material.dim, material.lam, material.mu,
                             full_family_sum(*args)), args


def bond_energy_time_step_c(material) -> float:
    """The Silling-Askari micromodulus of the bond-energy solid (bond_energy.py)."""
    from ..pd.bond_energy import time_step_micromodulus

    beta, args = _bond_energy_scale(material)
    return time_step_micromodulus(*args, beta, material.lam, material.mu)


def make_chapter5_model(material, s0: float, c_dt: float):
    """The model object of ``model = "bond_energy"`` or ``"viscoelastic_lps"``."""
    prm = material.params
    if prm["model"] == "bond_energy":
        from ..pd.bond_energy import BondEnergy

        beta, _ = _bond_energy_scale(material)
        return BondEnergy(material.dim, material.lam, material.mu, beta,
                          bond_yield_energy(material, beta), s0, c_dt, material.clamp_faces,
                          material.clamp_array())
    from ..pd.viscoelastic_lps import ViscoelasticLPS

    return ViscoelasticLPS(material.bulk, material.mu, prm["relaxation_time"], prm["memory"],
                           s0, c_dt, material.clamp_faces, material.clamp_array())

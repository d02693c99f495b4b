"""Peridynamic bodies (003 ch. 4-5): ``type = "peridynamic"`` with a bond ``model``.

``integration = "pd"``: the particles are off the grid and move by their own bond forces (003
Alg. 2: failure, theta or K/F, force eq. 4.1, symplectic Euler, gravity). ``integration =
"grid"`` (integral-based MPM, 003 ch. 5): the particles are ordinary MPM particles whose
internal force reaches the grid through the force channel, f_i = sum_p w_ip f_p with
f_p = V_p sum_q (T_p<X> - T_q<-X>) V_q (eq. 5.2 corrected: the print multiplies by m_p and
V_p^n and lacks the quadrature volume), instead of -sum_p V_p sigma_p grad w_ip: the material's
Kirchhoff stress is zero. The PD work itself is the step extension `hpcmpm.pd.extension`.

Models and their constants: hpcmpm/pd/{pmb,lps,correspondence,moduli}.py. 2D volumes are
areas (unit thickness): the 2D micromodulus c = 12 kappa/(pi h delta^3) times V_q = A h does
not depend on h, so there is no thickness parameter. The PMB needs the
Poisson ratio it can represent (3D and plane strain 1/4, plane stress 1/3); ``critical_stretch``
or ``fracture_energy`` (s0 from G0, moduli.critical_stretch) sets failure; every model also
breaks a bond past ``max_bond_stretch`` (the PD halo's reach). ``correspondence`` evaluates the
stress of another material of the scene (``stress_material``, an elastic model of F) at the PD
deformation gradient, with Silling's zero-energy-mode control ``stabilization`` (times the PMB
micromodulus of the same bulk modulus).

``clamp`` (not in 003): an integral-based body next to a sticky domain wall is bonded to the
mirror image of its family there (hpcmpm/pd/clamp.py, as the SPB coupling's clamp), so the
wall holds it as a clamped end and not only through the grid nodes. "auto" (the default)
turns it on for every ``model`` with ``integration = "grid"`` and leaves it off for the
off-grid integrator; "sticky_walls" asks for it (an error off the grid, where the walls act
per particle); "none" turns it off. On the axial bar
(inputs/ibmpm_bar_2d.toml) it takes the correspondence period error from first order
(1.15 % / 0.60 % at 25 / 50 cells) to second (0.11 % / 0.022 %): the wall cut the families
of the fixed end.
"""

from __future__ import annotations

import math

import numpy as np

from ..pd.clamp import (NO_CLAMP, NO_FACES, clamp_parameters, faces_within_reach,
                        share_within_reach, sticky_faces)
from ..pd.families import (DEFAULT_HORIZON, INFLUENCES, family_radius, full_family_sum,
                           half_bonds_per_particle, horizon_length, horizon_problem,
                           influence_code)
from ..pd import moduli
from ..pd.load import ACTIVE_BONDS
from ..state import SCALAR, VECTOR, FieldSpec
from .base import ElasticMaterial, Material
from .params import YOUNG, Param, choice, resolve_params
from .pd_models import (EXTRA_PARAMETERS, bond_yield_description, check_chapter5,
                        has_bond_plasticity)


def _point(x) -> str:
    return "[" + ", ".join(f"{v:g}" for v in x) + "]"


def _is_bool(value):
    return None if isinstance(value, bool) else f"must be true or false, got {value!r}"


def _is_name(value):
    return None if isinstance(value, str) and value else f"must be a material name, got {value!r}"


def _precracks(value):
    """2D: a list of segments [[x1, y1], [x2, y2]]; 3D: a list of planar polygons, each a list
    of >= 3 vertices [x, y, z]."""
    try:
        cracks = [np.asarray(c, dtype=np.float64) for c in value]
    except (TypeError, ValueError):
        return "must be a list of segments (2D) or polygons (3D) of coordinates"
    for c in cracks:
        if c.ndim != 2 or c.shape[1] not in (2, 3) or len(c) < 2 or not np.all(np.isfinite(c)):
            return "each pre-crack must be a list of points [x, y] (2D) or [x, y, z] (3D)"
    return None


class Peridynamic(Material):
    """A PD body (module docstring)."""

    name = "peridynamic"
    parameters = {
        "model": choice(("pmb", "lps", "correspondence", "bond_energy", "viscoelastic_lps"),
                        "pmb", "bond model"),
        "integration": choice(("pd", "grid"), "pd",
                              "pd: own bond forces (003 Alg. 2); grid: integral-based MPM"),
        "E": YOUNG,
        "nu": Param(-1.0, 0.5, False, 0.25, doc="Poisson ratio (PMB: 1/4, plane stress 1/3)"),
        "plane": choice(("strain", "stress"), "strain", "2D: plane strain or plane stress"),
        "horizon": Param(1.0, math.inf, False, DEFAULT_HORIZON, low_inclusive=True,
                         doc="horizon delta in particle spacings"),
        "horizon_length": Param(0.0, math.inf, False, None, doc="horizon delta (length)"),
        "partial_volumes": Param(-math.inf, math.inf, False, True, check=_is_bool,
                                 doc="PA-HHB partial volumes at the horizon edge"),
        "influence": choice(INFLUENCES, "constant", "influence function omega(|X|)"),
        "critical_stretch": Param(0.0, math.inf, False, math.inf, high_inclusive=True,
                                  doc="bond failure stretch s0 (003 eq. 4.8)"),
        "fracture_energy": Param(0.0, math.inf, False, None,
                                 doc="G0: sets s0 (overrides critical_stretch)"),
        "max_bond_stretch": Param(0.0, math.inf, False, 1.0,
                                  doc="stretch beyond which any bond breaks (halo reach)"),
        "stabilization": Param(0.0, math.inf, False, 0.1, low_inclusive=True,
                               doc="correspondence: zero-energy-mode penalty, times c"),
        "stress_material": Param(-math.inf, math.inf, False, None, check=_is_name,
                                 doc="correspondence: the material whose stress it uses"),
        "skin": Param(0.0, math.inf, False, 1.0, doc="PD halo skin in particle spacings"),
        "clamp": choice(("auto", "sticky_walls", "none"), "auto",
                        "mirror-image bonds at sticky domain walls (hpcmpm/pd/clamp.py); "
                        "auto: on for integral-based bodies (integration = grid), off "
                        "for integration = pd"),
        # Models of 003 ch. 5: materials/pd_models.py.
        **EXTRA_PARAMETERS,
        "precracks": Param(-math.inf, math.inf, False, None, check=_precracks,
                           doc="segments (2D) or planar polygons (3D) no bond crosses"),
    }
    # Reference positions (NaN until the first PD phase copies x), the LPS weighted volume,
    # the damage denominator, the damage phi (003 eq. 4.8) for frames, and the active
    # half-bonds (-1 until the bonds are made) that weigh the particle for load balance.
    fields = {"x0": FieldSpec(VECTOR, "f8", math.nan), "pd_m": FieldSpec(SCALAR),
              "pd_wvol0": FieldSpec(SCALAR), "damage": FieldSpec(SCALAR),
              "active_bonds": ACTIVE_BONDS}
    deformation = "F"

    def __init__(self, spec, dim: int):
        super().__init__(spec, dim)
        prm = self.params
        self.on_grid = prm["integration"] == "grid"
        E, nu, plane = prm["E"], prm["nu"], prm["plane"]
        where = f"material {spec.name!r} ({self.name})"
        check_chapter5(prm, where)      # keys of the 003 ch. 5 models (pd_models.py)
        self.bulk = moduli.bulk_modulus(dim, E, nu, plane)
        self.mu = moduli.shear_modulus(E, nu)
        # Lamé pair of the same (3D or plane strain) solid, for the wave speed.
        self.lam = self.bulk - 2.0 * self.mu / dim
        self.stress_model = None
        self.spacing = math.nan
        self.delta = math.nan
        self.clamp_faces = NO_FACES
        self.ghost_fraction = 0.0       # of the particles within reach of a clamped face
        self._dt_limit = None           # ((spacing, delta), dt_limit): `dt_limit`

    @staticmethod
    def clamp_supported(prm) -> bool:
        """Where the clamp's ghost bonds are implemented (clamp.py): every model on the grid
        (off it, the walls act on each particle)."""
        return prm["integration"] == "grid"

    @classmethod
    def scene_problems(cls, spec, scene) -> list[str]:
        """The issue's bad input that needs the scene (the scene validator reports each with
        its TOML path): a PMB Poisson ratio the dimension cannot represent, a horizon below
        one particle spacing, a pre-crack of the wrong dimension or outside the domain, a
        correspondence model without an elastic stress material."""
        from . import MATERIALS

        prm = resolve_params(cls.parameters, dict(spec.params))
        dim, out = scene.dim, []
        if prm["model"] == "pmb":
            problem = moduli.check_pmb_poisson(dim, prm["nu"], prm["plane"])
            if problem:
                out.append(problem)
        spacing = scene.dx / scene.particles_per_cell
        if prm["horizon_length"] is not None and prm["horizon_length"] < spacing:
            out.append(f"horizon_length: {prm['horizon_length']:g} is below one particle "
                       f"spacing {spacing:g} (simulation.dx / particles_per_cell)")
        key = "horizon_length" if prm["horizon_length"] is not None else "horizon"
        spacings = prm["horizon"] if key == "horizon" else prm["horizon_length"] / spacing
        too_wide = horizon_problem(dim, spacings)
        if too_wide:  # the checks below would build lattices of its size
            return out + [f"{key}: {too_wide}"]
        lo, hi = np.asarray(scene.domain_lo), np.asarray(scene.domain_hi)
        # A period within the family radius puts a particle's own images in its family:
        # bonds of zero reference length once resolved (an LPS strip 1 cell wide, horizon
        # 3.015 spacings: 2 such bonds per particle, a numerical instability at step 1).
        radius = family_radius(horizon_length(spacing, prm["horizon"], prm["horizon_length"]),
                               spacing, prm["partial_volumes"])
        for axis, period in scene.periods():
            if period <= radius:
                out.append(f"{key}: the family radius {radius:g} reaches across the period "
                           f"{period:g} of the periodic axis {'xyz'[axis]}: a particle would "
                           f"bond to its own image (the domain must be wider than "
                           f"{radius:g} along {'xyz'[axis]}, or the horizon shorter)")
        for k, c in enumerate(prm["precracks"] or ()):
            c = np.asarray(c, dtype=np.float64)
            if c.shape[1] != dim or (dim == 2 and len(c) != 2) or (dim == 3 and len(c) < 3):
                out.append(f"precracks[{k}]: must be " + (
                    "a segment of two points [x, y]" if dim == 2
                    else "a planar polygon of >= 3 points [x, y, z]"))
            elif np.any(c < lo) or np.any(c > hi):
                out.append(f"precracks[{k}]: outside the domain (lower {_point(lo)}, "
                           f"upper {_point(hi)})")
        if prm["clamp"] == "sticky_walls" and not cls.clamp_supported(prm):
            out.append(f"clamp: 'sticky_walls' needs integration = 'grid' (off the grid the "
                       f"walls act on each particle; this body: integration = "
                       f"{prm['integration']!r}); use 'auto' or 'none'")
        if prm["model"] == "correspondence":
            names = [m.name for m in scene.materials]
            other = prm["stress_material"]
            if not other:
                out.append("stress_material: missing (the correspondence model evaluates "
                           "another material's stress)")
            elif other not in names:
                out.append(f"stress_material: no material named {other!r} (have: "
                           f"{', '.join(names)})")
            elif not issubclass(MATERIALS[scene.materials[names.index(other)].type],
                                ElasticMaterial):
                out.append(f"stress_material: {other!r} is not an elastic model of F alone")
        return out

    def configure(self, scene) -> None:
        prm = self.params
        self.spacing = scene.dx / scene.particles_per_cell
        self.delta = horizon_length(self.spacing, prm["horizon"], prm["horizon_length"])
        if prm["model"] == "correspondence":
            from . import make_material

            names = [m.name for m in scene.materials]
            self.stress_model = make_material(
                scene.materials[names.index(prm["stress_material"])], self.dim)
        if prm["clamp"] != "none" and self.clamp_supported(prm):
            from ..scene import body_bounds

            # Only the walls this material's bodies start within a family radius of.
            boxes = [body_bounds(b.shape, b.params, self.dim) for b in scene.bodies
                     if b.material == self.spec.name]
            self.clamp_faces = faces_within_reach(sticky_faces(scene), boxes,
                                                  self.family_radius())
            self.ghost_fraction = share_within_reach(self.clamp_faces, boxes,
                                                     self.family_radius())

    def notes(self) -> list[str]:
        """Bond plasticity's psi_p with the yield stretch it amounts to at this spacing."""
        line = bond_yield_description(self)
        return [line] if line else []

    def clamp_array(self) -> np.ndarray:
        """The kernels' clamp parameters (clamp.clamp_parameters); unused without faces."""
        if not len(self.clamp_faces):
            return NO_CLAMP
        prm = self.params
        return clamp_parameters(self.delta, self.spacing, influence_code(prm["influence"]),
                                bool(prm["partial_volumes"]))

    def family_radius(self) -> float:
        """The largest bond length of this material's families (families.family_radius)."""
        return family_radius(self.delta, self.spacing, self.params["partial_volumes"])

    def half_bonds_per_particle(self) -> int:
        """Half-bonds of an interior particle (the memory estimate before allocation)."""
        return half_bonds_per_particle(self.dim, self.delta / self.spacing,
                                       self.params["partial_volumes"])

    def bond_state_names(self) -> tuple[str, ...]:
        """The per-bond state arrays this material's model keeps (pd/bonds.py ``state``):
        the bond-energy plastic stretch (with plasticity), the viscoelastic stored forces and
        lengths."""
        model = self.params["model"]
        if model == "bond_energy":
            from ..pd.bond_energy import PLASTIC_STATE

            return (PLASTIC_STATE,) if has_bond_plasticity(self.params) else ()
        if model == "viscoelastic_lps":
            from ..pd.viscoelastic_lps import state_fields

            return state_fields(self.params["memory"])
        return ()

    def ghost_state_names(self) -> tuple[str, ...]:
        """The states of the clamp's ghost store (clamp.ghost_store) for the bond-energy
        plasticity and the viscoelastic history (after `configure`: it depends on the
        walls)."""
        nf, model = len(self.clamp_faces), self.params["model"]
        if model == "bond_energy" and has_bond_plasticity(self.params):
            from ..pd.bond_energy import mirror_state_names

            return mirror_state_names(nf)
        if model == "viscoelastic_lps":
            from ..pd.viscoelastic_lps import ghost_state_names

            return ghost_state_names(nf, self.params["memory"])
        return ()

    def side_bytes_per_particle(self) -> float:
        """The bonds of an interior particle: its half-bonds times the resident bytes of one
        with the model's per-bond states (pd/bonds.py) plus 4 B of the family search's
        scratch per half-bond; and the clamp's ghost store, one entry per half-bond and one
        for the particle's own image, priced for the fraction of the bodies' bounding boxes
        within reach of a clamped wall."""
        from ..pd.bonds import Bonds

        n = self.half_bonds_per_particle()
        one = Bonds.empty(state_names=self.bond_state_names()).resident_bytes_per_bond()
        ghost_names = self.ghost_state_names()
        ghost = Bonds.empty(state_names=ghost_names).resident_bytes_per_bond() \
            if ghost_names else 0
        return n * (one + 4) + self.ghost_fraction * (n + 1) * ghost

    # -- PD constants ------------------------------------------------------------------------
    def micromodulus(self) -> float:
        """c of the PMB solid with this bulk modulus (the PMB's own; correspondence
        stabilization scale)."""
        prm = self.params
        return moduli.pmb_micromodulus(self.dim, self.bulk, self.delta, prm["influence"])

    def time_step_micromodulus(self) -> float:
        """c for the Silling-Askari step: the PMB's own, else the PMB solid with the same
        P-wave modulus."""
        if self.params["model"] == "pmb":
            return self.micromodulus()
        if self.params["model"] == "bond_energy":      # 003 ch. 5: materials/pd_models.py
            from .pd_models import bond_energy_time_step_c
            return bond_energy_time_step_c(self)
        return moduli.equivalent_micromodulus(self.dim, self.bulk, self.mu, self.delta,
                                              self.params["influence"])

    def critical_stretch(self) -> float:
        prm = self.params
        s0 = prm["critical_stretch"]
        if prm["fracture_energy"] is not None:
            s0 = moduli.critical_stretch(self.dim, prm["fracture_energy"],
                                         self.micromodulus(), self.delta, prm["influence"])
        return min(s0, prm["max_bond_stretch"])

    def make_model(self):
        from ..pd.correspondence import Correspondence
        from ..pd.lps import LPS
        from ..pd.pmb import PMB

        prm, s0, c_dt = self.params, self.critical_stretch(), self.time_step_micromodulus()
        if prm["model"] == "pmb":
            return PMB(self.micromodulus(), s0, self.clamp_faces, self.clamp_array())
        if prm["model"] == "lps":
            return LPS(self.bulk, self.mu, s0, c_dt, self.clamp_faces, self.clamp_array())
        if prm["model"] in ("bond_energy", "viscoelastic_lps"):   # materials/pd_models.py
            from .pd_models import make_chapter5_model
            return make_chapter5_model(self, s0, c_dt)
        other = self.stress_model

        def stress(F, tau):
            other.update_stress({"F": np.ascontiguousarray(F), "tau": tau}, 0.0)

        def energy(F, vol):
            return other.energy({"F": np.ascontiguousarray(F), "vol0": vol})

        return Correspondence(self.dim, stress, prm["stabilization"] * self.micromodulus(), s0,
                              c_dt, energy=energy, clamp_faces=self.clamp_faces,
                              clamp=self.clamp_array())

    def make_extension(self, sim):
        """The step extension that does the PD work: bond forces on the grid (integral-based
        MPM) or moving the particles themselves (hpcmpm/pd/extension.py), with crack planes
        for ``crack_threshold`` (003 §5.4, hpcmpm/pd/crack_planes.py)."""
        if self.params.get("crack_threshold") is not None:
            from ..pd.crack_planes import make_crack_plane_extension

            return make_crack_plane_extension(sim, self)
        from ..pd.extension import IntegralMPMExtension, PDBodyExtension

        return (IntegralMPMExtension if self.on_grid else PDBodyExtension)(sim, self)

    # -- the Material interface --------------------------------------------------------------
    def wave_speed(self) -> float:
        """P-wave speed for the grid CFL bound; 0 off the grid (integration "pd": the PD
        step rule `dt_limit` bounds the step instead)."""
        return super().wave_speed() if self.on_grid else 0.0

    def dt_limit(self, dx: float) -> float:
        """0.8 sqrt(2 rho / sum_q V_q c w/|X|) over a full lattice family (the most bonds a
        particle has; the issue's rule), the same on every rank. A constant of the material:
        computed once per family geometry (its lattice sums took 0.4 ms, asked every step)."""
        key = (self.spacing, self.delta)
        if self._dt_limit is None or self._dt_limit[0] != key:
            stiffness = self.time_step_micromodulus() * full_family_sum(
                self.dim, self.spacing, self.delta, self.params["influence"],
                bool(self.params["partial_volumes"]), power=-1)
            self._dt_limit = (key, 0.8 * math.sqrt(2.0 * self.density / stiffness))
        return self._dt_limit[1]

    def return_map(self, fields, dt) -> None:
        """F stays the identity: the PD state lives in the bonds, and a grid-advanced F of a
        fractured particle must not trip the det F guard (detached particles carry no
        stress)."""
        if "F" in fields:
            F = fields["F"]
            F[...] = 0.0
            for a in range(self.dim):
                F[:, a, a] = 1.0

    def update_stress(self, fields, dt) -> None:
        """No continuum stress: the bond forces reach the grid through the force channel."""
        fields["tau"][...] = 0.0

    def energy(self, fields) -> float:
        """0 here: the bond strain energy is the PD extension's (bonds are not particle
        fields), `PDExtension.strain_energy`, which the diagnostics add."""
        return 0.0

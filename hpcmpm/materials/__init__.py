"""Constitutive models, looked up by the scene's material ``type``.

`MATERIALS` maps each type name to its class; `make_material(spec, dim)` builds one and
`validate_params(type, params)` lists what is wrong with a material's parameters (the format of
each class's ``parameters`` schema is documented in `hpcmpm.materials.params`).
"""

from __future__ import annotations

import difflib
from typing import Any

from ..errors import SceneError
from .base import ElasticMaterial, Material
from .fixed_corotated import FixedCorotated
from .herschel_bulkley import HerschelBulkley
from .j2 import J2Plasticity
from .linear_elastic import LinearElastic
from .neo_hookean import NeoHookean
from .oldroyd_b import OldroydB
from .params import Param, check_params, lame
from .peridynamic import Peridynamic
from .shock import ShockModel
from .snow import Snow
from .stable_neo_hookean import StableNeoHookean
from .von_mises import VonMises
from .weakly_compressible import WeaklyCompressible

MATERIALS: dict[str, type[Material]] = {
    cls.name: cls
    for cls in (LinearElastic, FixedCorotated, NeoHookean, StableNeoHookean, Snow,
                WeaklyCompressible, OldroydB, HerschelBulkley, VonMises, ShockModel,
                J2Plasticity, Peridynamic)
}


def _unknown_type(type_name: str) -> str:
    close = difflib.get_close_matches(str(type_name), list(MATERIALS), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return (f"type: unknown material type {type_name!r} ({hint}valid: "
            f"{', '.join(sorted(MATERIALS))})")


def validate_params(type_name: str, params: dict[str, Any]) -> list[str]:
    """One problem string per missing, unknown or out-of-range parameter of a material of
    type ``type_name`` (or one string naming the valid types when the type is unknown)."""
    cls = MATERIALS.get(type_name)
    if cls is None:
        return [_unknown_type(type_name)]
    return cls.parameter_problems(params)


def make_material(spec, dim: int) -> Material:
    """The material object for a `MaterialSpec` (``spec.type`` picks the class). Raises
    `SceneError` for an unknown type or invalid parameters."""
    cls = MATERIALS.get(spec.type)
    if cls is None:
        raise SceneError(f"material {spec.name!r}: {_unknown_type(spec.type)}")
    return cls(spec, dim)


__all__ = ["MATERIALS", "ElasticMaterial", "Material", "Param", "check_params", "lame",
           "make_material", "validate_params", "FixedCorotated", "LinearElastic", "NeoHookean",
           "StableNeoHookean", "Snow", "WeaklyCompressible", "OldroydB", "HerschelBulkley",
           "VonMises", "ShockModel", "J2Plasticity", "Peridynamic"]

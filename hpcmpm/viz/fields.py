"""What a picture is coloured by: a frame dataset, one component of it, or a derived quantity.

``NAME[:COMPONENT]``: NAME is a dataset of ``/particles`` (``material``, ``J``, ``Jp``, ``tau``,
``damage``, ... whatever the run wrote) or a derived field: ``speed`` = |v| (the default),
``J`` = det F where the frame holds F, ``pressure`` = -tr(tau) / (d J) where it holds the
Kirchhoff stress tau. COMPONENT picks a scalar from a vector (``x``, ``y``, ``z`` or an index;
default: the magnitude) or a tensor (``xy`` or ``0,1`` or a flat row-major index, ``det``,
``trace``; default: the Frobenius norm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .series import RenderError

AXES = "xyz"
# Derived field -> the datasets it is computed from (pressure: tau and either J or F).
DERIVED = {"speed": ("v",), "J": ("F",), "pressure": ("tau",)}


@dataclass(frozen=True)
class FieldChoice:
    name: str
    component: str | None = None

    @property
    def label(self) -> str:
        return self.name if self.component is None else f"{self.name}:{self.component}"

    @property
    def categorical(self) -> bool:
        return self.name == "material" and self.component is None


def parse_field(spec: str | None) -> FieldChoice:
    if spec is None or not spec.strip():
        return FieldChoice("speed")
    name, _, component = spec.strip().partition(":")
    if not name:
        raise RenderError(f"--field {spec!r}: expected NAME[:COMPONENT], e.g. speed, v:x, F:xy")
    return FieldChoice(name, component.strip() or None)


def available_fields(shapes: dict[str, tuple[int, ...]]) -> list[str]:
    """Field names a frame with datasets of these shapes can be coloured by."""
    names = set(shapes)
    names |= {d for d, needs in DERIVED.items() if all(n in shapes for n in needs)}
    if "pressure" not in shapes and not ("J" in shapes or "F" in shapes):
        names.discard("pressure")
    return sorted(names)


def datasets_needed(choice: FieldChoice, shapes: dict[str, tuple[int, ...]]) -> list[str]:
    """The datasets to read for ``choice``; a `RenderError` listing the fields when it has none."""
    if choice.name in shapes:
        return [choice.name]
    if choice.name in available_fields(shapes):
        if choice.name == "pressure":
            return ["tau", "J" if "J" in shapes else "F"]
        return list(DERIVED[choice.name])
    raise RenderError(f"no field {choice.name!r} in the frames; fields: "
                      f"{', '.join(available_fields(shapes))}")


def field_values(choice: FieldChoice, data: dict[str, np.ndarray], dim: int) -> np.ndarray:
    """The scalar (n,) that colours each particle."""
    name = choice.name
    if name in data:
        values = data[name]
    elif name == "speed":
        values = data["v"]
    elif name == "J":
        values = np.linalg.det(data["F"])
    elif name == "pressure":
        J = data["J"] if "J" in data else np.linalg.det(data["F"])
        values = -np.trace(data["tau"], axis1=1, axis2=2) / (dim * J)
    else:
        raise RenderError(f"no field {name!r} in this frame")
    return reduce_to_scalar(np.asarray(values), choice)


def reduce_to_scalar(values: np.ndarray, choice: FieldChoice) -> np.ndarray:
    n = values.shape[0]
    trailing = values.shape[1:]
    comp = choice.component
    if trailing == ():
        if comp is not None:
            raise RenderError(f"--field {choice.label}: {choice.name} is a scalar, "
                              f"it has no component {comp!r}")
        return values.astype(np.float64)
    flat = values.reshape(n, -1).astype(np.float64)
    if comp is None or comp == "norm":
        return np.sqrt(np.einsum("ij,ij->i", flat, flat))
    if len(trailing) == 2 and trailing[0] == trailing[1]:
        if comp == "det":
            return np.linalg.det(values.astype(np.float64))
        if comp == "trace":
            return np.trace(values, axis1=1, axis2=2).astype(np.float64)
    index = _component_index(comp, trailing)
    if index is None:
        raise RenderError(f"--field {choice.label}: no component {comp!r} in {choice.name} of "
                          f"shape {trailing}; use {_component_help(trailing)}")
    return flat[:, index]


def _component_index(comp: str, trailing: tuple[int, ...]) -> int | None:
    size = int(np.prod(trailing))
    if comp.isdigit():
        return int(comp) if int(comp) < size else None
    if len(trailing) == 1 and len(comp) == 1 and comp in AXES[:trailing[0]]:
        return AXES.index(comp)
    if len(trailing) == 2:
        rows, cols = trailing
        if len(comp) == 2 and all(c in AXES for c in comp):
            i, j = AXES.index(comp[0]), AXES.index(comp[1])
        elif "," in comp:
            try:
                i, j = (int(s) for s in comp.split(","))
            except ValueError:
                return None
        else:
            return None
        return i * cols + j if i < rows and j < cols else None
    return None


def _component_help(trailing: tuple[int, ...]) -> str:
    size = int(np.prod(trailing))
    if len(trailing) == 1:
        return f"{', '.join(AXES[:trailing[0]])}, 0..{size - 1} or norm"
    return f"xy-style pairs, i,j, 0..{size - 1}, det, trace or norm"

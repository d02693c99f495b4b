"""Views of rank-local grid blocks as 3D arrays, so one kernel serves 2D and 3D.

A 2D block of shape (n0, n1) is viewed as (n0, n1, 1): the third loop has one trip and the
kernels branch on ``dim`` only outside the arithmetic that differs. Reshaping a C-contiguous
array is a view, so kernels still write in place; a non-contiguous array would be silently
copied, hence the check.
"""

from __future__ import annotations

import numpy as np

# Stands in for ``mass`` when the caller passes none; never indexed (``use_mass`` is False).
NO_MASS = np.zeros((1, 1, 1))


def block3(array: np.ndarray, dim: int) -> np.ndarray:
    """``array`` of shape ``block + trailing`` as ``block3 + trailing`` (a view)."""
    if not array.flags.c_contiguous:
        raise ValueError("grid arrays must be C-contiguous so boundary kernels act in place")
    if dim == 3:
        return array
    return array.reshape(array.shape[:2] + (1,) + array.shape[2:])


def mass3(mass: np.ndarray | None, dim: int) -> tuple[np.ndarray, bool]:
    """The mass view and whether to skip massless nodes."""
    if mass is None:
        return NO_MASS, False
    return block3(np.asarray(mass, dtype=np.float64), dim), True


def vec3(values, dim: int) -> np.ndarray:
    """A dim-vector padded with zeros to 3 components (2D lives in the z = 0 plane)."""
    out = np.zeros(3)
    if values is not None and len(values):
        out[:dim] = np.asarray(values, dtype=np.float64)[:dim]
    return out


def omega3(angular, dim: int) -> np.ndarray:
    """Angular velocity as a 3-vector; in 2D the scene gives a scalar rate about z."""
    if angular is None:
        return np.zeros(3)
    if dim == 2:
        return np.array([0.0, 0.0, float(np.ravel(np.asarray(angular, dtype=np.float64))[-1])])
    return np.asarray(angular, dtype=np.float64).reshape(3).copy()

"""Reference positions on periodic axes.

The engine wraps positions x into the domain along periodic axes and moves a particle's
reference position x0 by the same whole periods (`Domain.wrap_particles`), so x - x0 stays
the displacement however far a body travels, and the reference bond X = x0_q - x0_p between
a particle and the copy of a partner that the halo holds is the same before and after either
crosses a face. A search for new bonds (SPB-MPM's conversions) brings every reference
position into the box first and adds the images of those near its faces
(`canonical_images`)."""

from __future__ import annotations

import numpy as np


def canonical_images(lo: np.ndarray, period: np.ndarray, x0: np.ndarray, reach: float):
    """Reference positions brought into the periodic box [lo, lo + period) and the images of
    those within ``reach`` of its faces: (shift (n, d) added to each row to bring it in,
    image source rows (m,), image shifts (m, d)). A row's current position moves with the
    same shift (x - x0 is kept). Non-periodic axes (period 0) are left alone."""
    from .families import periodic_images

    periodic = period > 0
    safe = np.where(periodic, period, 1.0)
    shift = np.where(periodic, -np.floor((x0 - lo) / safe) * safe, 0.0)
    src, img_shift = periodic_images(x0 + shift, lo, period, reach)
    return shift, src, img_shift

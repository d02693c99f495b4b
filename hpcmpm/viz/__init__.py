"""Pictures of runs: ``hpcmpm render`` (PNGs + a movie), ``hpcmpm plot`` (diagnostics to PNG +
CSV), and the line plots every study and verification figure is drawn with.

Built on matplotlib (Agg canvas, no display), Pillow, a numba sphere-splatting kernel for 3D,
and ffmpeg from the ``imageio-ffmpeg`` wheel for MP4 (animated GIF without it). Modules:
``series`` (frames in XDMF order, scene geometry), ``fields`` (what colours the particles),
``layout`` (figure, colour bar, title), ``render2d`` / ``render3d``, ``movie``, ``render``
(the verb, frames split over MPI ranks), ``diagnostics`` (the plot verb), ``plots``.
Matplotlib is imported only inside functions, so ``import hpcmpm`` stays light.
"""

from .series import RenderError

__all__ = ["RenderError"]

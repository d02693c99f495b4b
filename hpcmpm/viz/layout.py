"""The frame of every picture: a figure of exactly W x H pixels with the scene's view on the
left, a colour bar on the right and the scene name and time on top; the colour scale.

Matplotlib is driven through its object API on an Agg canvas (no pyplot, no global backend
switch), so rendering works without a display and leaves a user's matplotlib state alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .fields import FieldChoice

DPI = 100
BACKGROUND = "white"


@dataclass
class ColourScale:
    """Colour map and normalisation shared by every frame of a render (one fixed scale, so the
    movie's colours mean the same throughout)."""

    cmap: object
    norm: object
    label: str
    ticks: list | None = None
    ticklabels: list | None = None

    def rgba(self, values: np.ndarray) -> np.ndarray:
        return self.cmap(self.norm(values))


# A field whose values spread by less than this fraction of their magnitude is drawn as
# uniform: 1e-12 is about 4500 ulp, above the round-off a run accumulates in a quantity that is
# uniform in exact arithmetic, and far below any variation a 256-level colour map shows
# as physics.
ROUND_OFF_SPREAD = 1e-12


def colour_scale(choice: FieldChoice, lo: float, hi: float,
                 material_names: list[str] | None = None) -> ColourScale:
    """Discrete colours for the material index, viridis over [lo, hi] for anything else."""
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm, ListedColormap, Normalize

    if choice.categorical:
        names = list(material_names or [])
        count = max(len(names), int(hi) + 1 if math.isfinite(hi) else 1, 1)
        base = colormaps["tab10"].colors
        cmap = ListedColormap([base[i % len(base)] for i in range(count)])
        norm = BoundaryNorm(np.arange(count + 1) - 0.5, count)
        labels = [names[i] if i < len(names) else str(i) for i in range(count)]
        return ColourScale(cmap, norm, "material", list(range(count)), labels)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = 0.0, 1.0
    if hi - lo <= ROUND_OFF_SPREAD * max(abs(lo), abs(hi)):
        # A uniform field, or one whose spread is round-off (two disks in free flight: speed
        # 0.1414213562 +- 1e-15 was drawn in the full colour map, its bar labelled
        # "1e-15 + 1.414213562e-1"): a small band around the value, so the bar still reads.
        mid = 0.5 * (lo + hi)
        if mid == 0.0:
            # Zero everywhere (damage before any bond breaks, a velocity component at rest):
            # [0, 1], the colour other frames give 0, and no negative ticks on the bar of a
            # quantity that cannot be negative.
            lo, hi = 0.0, 1.0
        else:
            pad = 0.05 * abs(mid)
            lo, hi = mid - pad, mid + pad
    cmap = colormaps["viridis"].with_extremes(bad="0.6")
    return ColourScale(cmap, Normalize(lo, hi), choice.label)


class Canvas:
    """A figure of ``size`` = (W, H) pixels: ``view`` axes, a colour bar, a title line."""

    def __init__(self, size: tuple[int, int], scale: ColourScale, title: str):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.cm import ScalarMappable
        from matplotlib.figure import Figure

        self.width, self.height = size
        self.figure = Figure(figsize=(self.width / DPI, self.height / DPI), dpi=DPI,
                             facecolor=BACKGROUND)
        self.canvas = FigureCanvasAgg(self.figure)
        font = max(6.0, min(self.width / 45, self.height / 30, 13.0))  # points
        self.font = font
        bar_w = max(8, round(0.025 * self.width))
        label_w = round(4.8 * font * DPI / 72)  # room for tick labels and the bar's label (px)
        top = round(2.2 * font * DPI / 72)
        # From the width, but no more than a wide and low picture has room for (8192 x 64
        # had a margin of 164 px and a view of negative height).
        margin = max(4, round(0.02 * min(self.width, 1.5 * self.height)))
        # The view's rectangle in whole pixels, so a raster drawn into it maps 1:1.
        self.view_px = (margin, margin, self.width - 2 * margin - bar_w - label_w,
                        self.height - top - margin)  # left, bottom, width, height
        left, bottom, w, h = self.view_px
        self.view = self.figure.add_axes((left / self.width, bottom / self.height,
                                          w / self.width, h / self.height))
        self.view.set_axis_off()
        bar = self.figure.add_axes(((left + w + margin) / self.width,
                                    (bottom + 0.1 * h) / self.height,
                                    bar_w / self.width, 0.8 * h / self.height))
        mappable = ScalarMappable(norm=scale.norm, cmap=scale.cmap)
        colourbar = self.figure.colorbar(mappable, cax=bar)
        if scale.ticks is not None:
            colourbar.set_ticks(scale.ticks, labels=scale.ticklabels)
        colourbar.ax.tick_params(labelsize=0.8 * font)
        colourbar.set_label(scale.label, fontsize=font)
        self.title = self.figure.text(0.5, 1 - 0.6 * top / self.height, title, ha="center",
                                      va="center", fontsize=font)

    def set_title(self, text: str) -> None:
        self.title.set_text(text)

    def rgb(self) -> np.ndarray:
        """The figure as an (H, W, 3) uint8 array."""
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def frame_title(scene_name: str, time: float) -> str:
    return f"{scene_name}    t = {time:.4g}"

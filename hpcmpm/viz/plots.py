"""Line plots for diagnostics, studies and verification: one code path for every figure.

`plot_panels` draws panels of curves into one PNG (the diagnostics of ``hpcmpm plot``, the
error-against-cost study of scripts/study_error.py); `curve_against_reference` draws a
computed curve over its reference (analytic solution, published data) with their difference
underneath, and returns the difference so a verification test can assert on what it plots
(bar v_cm against the analytic cosine; later channel profiles, a Hugoniot, a crack path).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class Curve:
    x: Sequence[float]
    y: Sequence[float]
    label: str | None = None
    style: str = "-"  # matplotlib format string, e.g. "o-", "s--", "*:"
    colour: str | None = None
    size: float | None = None  # marker size
    every: int = 1  # draw a marker at every n-th point only (dense data)


@dataclass
class Panel:
    curves: list[Curve]
    xlabel: str = ""
    ylabel: str = ""
    title: str = ""
    logx: bool = False
    logy: bool = False
    legend_size: float = 8.0
    hline: float | None = None  # a reference level drawn dashed (e.g. 0 for an error)
    extra: dict = field(default_factory=dict)


def new_figure(width_in: float, height_in: float, rows: int = 1, cols: int = 1,
               sharex: bool = False):
    """A figure with a grid of axes on an Agg canvas (no pyplot state): (figure, axes 2D)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, sharex=sharex)
    return fig, axes


def draw_panel(ax, panel: Panel) -> None:
    for c in panel.curves:
        kwargs = {}
        if c.colour is not None:
            kwargs["color"] = c.colour
        if c.size is not None:
            kwargs["markersize"] = c.size
        if c.every > 1:
            kwargs["markevery"] = c.every
        ax.plot(np.asarray(c.x), np.asarray(c.y), c.style, label=c.label, **kwargs)
    if panel.hline is not None:
        ax.axhline(panel.hline, color="0.5", linestyle="--", linewidth=0.8)
    ax.set_xscale("log" if panel.logx else "linear")
    ax.set_yscale("log" if panel.logy else "linear")
    ax.set_xlabel(panel.xlabel)
    ax.set_ylabel(panel.ylabel)
    if panel.title:
        ax.set_title(panel.title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    if any(c.label for c in panel.curves):
        ax.legend(fontsize=panel.legend_size)


def save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def plot_panels(path, panels: list[Panel], title: str = "", cols: int = 1,
                panel_size: tuple[float, float] = (6.0, 3.0), sharex: bool = False) -> Path:
    """Panels in a grid of ``cols`` columns, saved as a PNG at ``path``."""
    rows = -(-len(panels) // cols)
    fig, axes = new_figure(panel_size[0] * cols, panel_size[1] * rows, rows, cols, sharex)
    for ax, panel in zip(axes.flat, panels):
        draw_panel(ax, panel)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    return save(fig, path)


def curve_against_reference(path, x, y, reference: Callable | tuple, *, label: str = "hpcmpm",
                            reference_label: str = "reference", xlabel: str = "",
                            ylabel: str = "", title: str = "",
                            relative_to: float | None = None) -> np.ndarray:
    """Plot a computed curve (x, y) over its reference and their difference; return the
    difference y - y_ref at x (divided by ``relative_to`` when given, as plotted).

    ``reference`` is a function y_ref(x) (evaluated at x and on a fine grid for the drawing)
    or tabulated (x_ref, y_ref), interpolated linearly at x (x_ref increasing)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if callable(reference):
        fine = np.linspace(x.min(), x.max(), 400)
        ref_curve, ref_at_x = (fine, reference(fine)), reference(x)
    else:
        xr, yr = (np.asarray(a, dtype=float) for a in reference)
        ref_curve, ref_at_x = (xr, yr), np.interp(x, xr, yr)
    difference = y - ref_at_x
    if relative_to:
        difference = difference / relative_to
    every = max(1, len(x) // 50)  # about 50 markers, so the reference stays visible
    plot_panels(path, [
        Panel([Curve(*ref_curve, reference_label, "-", "0.3"),
               Curve(x, y, label, "o", "C0", 3.5, every)], "", ylabel, title),
        Panel([Curve(x, difference, None, "o-" if every == 1 else "-", "C3", 3.0)], xlabel,
              "difference" + (f" / {relative_to:.3g}" if relative_to else ""), hline=0.0),
    ], sharex=True, panel_size=(6.0, 2.6))
    return difference

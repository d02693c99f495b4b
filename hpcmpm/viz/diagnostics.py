"""``hpcmpm plot RUN_DIR``: the run's diagnostics over time, from the frames' root attributes,
to ``diagnostics.csv`` and ``diagnostics.png``.

Every numeric root attribute of the frames is a column (a vector such as ``momentum`` one
column per component, ``momentum_x`` ...), except the bookkeeping ones (dimension, frame
number, rank count), so diagnostics that later features add to the frames (CG iterations,
broken bonds) appear without a change here. Values are written with ``repr`` (17 significant
digits), so the CSV holds exactly the float64 the frames hold.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from .plots import Curve, Panel, plot_panels
from .series import RenderError, list_frames

BOOKKEEPING = {"dim", "frame_index", "n_ranks"}
ENERGIES = ("kinetic_energy", "elastic_energy", "gravity_energy", "total_energy")


def collect(run_dir) -> tuple[list[str], list[dict]]:
    """(column names, one row per frame) of the frames' numeric attributes, in XDMF order."""
    import h5py

    rows = []
    for ref in list_frames(run_dir):
        with h5py.File(ref.path, "r") as h5:
            row = {"frame": ref.index}
            for key, value in h5.attrs.items():
                if key in BOOKKEEPING:
                    continue
                row.update(_numeric(key, value))
        rows.append(row)
    columns = ["frame", "time", "step"]
    for row in rows:
        columns += [k for k in row if k not in columns]
    return columns, rows


def _numeric(key: str, value) -> dict:
    if isinstance(value, str) and value.startswith("["):
        # Vectors are stored as JSON text (hpcmpm.io.shared.attr_value), floats by repr.
        try:
            value = json.loads(value)
        except ValueError:
            return {}
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return {}
    array = np.asarray(value)
    if array.dtype.kind not in "biuf" or array.ndim > 1:
        return {}
    if array.ndim == 0:
        return {key: array.item()}
    suffixes = "xyz" if len(array) <= 3 else [str(i) for i in range(len(array))]
    return {f"{key}_{s}": v.item() for s, v in zip(suffixes, array)}


def write_csv(path: Path, columns: list[str], rows: list[dict]) -> Path:
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in rows:
            writer.writerow(["" if row.get(c) is None else repr(row[c]) for c in columns])
    return path


def read_csv(path) -> dict[str, np.ndarray]:
    """Columns of a diagnostics CSV as float arrays (NaN where a frame lacks the value)."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        values = [[float(v) if v else np.nan for v in line] for line in reader]
    table = np.array(values, dtype=float).reshape(-1, len(header))
    return {name: table[:, i] for i, name in enumerate(header)}


def diagnostic_panels(columns: list[str], rows: list[dict]) -> list[Panel]:
    """Mass; momentum components; energies; then one panel per other quantity."""
    t = [r.get("time", np.nan) for r in rows]

    def curve(name, label=None):
        return Curve(t, [r.get(name, np.nan) for r in rows], label or name, ".-")

    panels, used = [], {"frame", "time", "step"}
    groups = [("mass", ["mass"]),
              ("momentum", [c for c in columns if c.startswith("momentum_")]),
              ("angular momentum", [c for c in columns if c.startswith("angular_momentum_")]),
              ("energy", [c for c in ENERGIES if c in columns])]
    for title, names in groups:
        if names:
            panels.append(Panel([curve(n) for n in names], "t", title))
            used.update(names)
    for name in columns:
        if name not in used:
            panels.append(Panel([curve(name)], "t", name))
    return panels


def plot_run(run_dir, out=None) -> tuple[Path, Path]:
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else run_dir
    columns, rows = collect(run_dir)      # first: a mistyped run folder is not created
    out.mkdir(parents=True, exist_ok=True)
    if "time" not in columns:
        raise RenderError(f"{run_dir}: the frames carry no 'time' attribute")
    csv_path = write_csv(out / "diagnostics.csv", columns, rows)
    panels = diagnostic_panels(columns, rows)
    png = plot_panels(out / "diagnostics.png", panels, f"{run_dir.resolve().name}: diagnostics",
                      cols=2, panel_size=(5.0, 2.8), sharex=False)
    return csv_path, png


def plot_command(args) -> int:
    csv_path, png = plot_run(args.run_dir, args.out)
    print(f"wrote {png} and {csv_path}")
    return 0

"""Open particles.xdmf in real ParaView (pvpython, offscreen): every time step has its points
and arrays. Skipped where ParaView is not installed."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
from test_io_frames import global_particles, write_frames

PVPYTHON = shutil.which("pvpython")
pytestmark = pytest.mark.skipif(
    PVPYTHON is None, reason="pvpython not installed (apt-get install paraview python3-paraview)")

PROBE = """
import json, sys
from paraview.simple import OpenDataFile
reader = OpenDataFile(sys.argv[1])
out = {"reader": reader.GetXMLName(), "times": list(reader.TimestepValues), "steps": []}
for t in reader.TimestepValues:
    reader.UpdatePipeline(t)
    info = reader.GetDataInformation()
    arrays = {name: reader.PointData[name].GetNumberOfComponents()
              for name in reader.PointData.keys()}
    out["steps"].append({"points": info.GetNumberOfPoints(), "bounds": list(info.GetBounds()),
                         "arrays": arrays})
print("RESULT " + json.dumps(out))
"""


@pytest.mark.parametrize("dim", [2, 3])
def test_paraview_opens_the_time_series(tmp_path, dim):
    values = global_particles(dim, 123, seed=dim)
    out = tmp_path / "run"
    write_frames(out, values, dim, 2, times=(0.0, 0.5, 1.0))
    probe = tmp_path / "probe.py"
    probe.write_text(PROBE)
    run = subprocess.run([PVPYTHON, "--force-offscreen-rendering", str(probe),
                          str(out / "particles.xdmf")], capture_output=True, text=True,
                         timeout=180)
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert run.returncode == 0 and lines, run.stdout + run.stderr
    result = json.loads(lines[-1][len("RESULT "):])
    assert result["reader"].startswith("Xdmf3Reader")
    assert result["times"] == [0.0, 0.5, 1.0]
    x = values["x"]
    for step in result["steps"]:
        assert step["points"] == 123
        assert step["arrays"] == {"id": 1, "mass": 1, "material": 1, "Jp": 1, "v": dim,
                                  "F": dim * dim}
        lo, hi = step["bounds"][0::2][:dim], step["bounds"][1::2][:dim]
        assert lo == pytest.approx(x.min(axis=0)) and hi == pytest.approx(x.max(axis=0))
        if dim == 2:
            assert step["bounds"][4:] == [0.0, 0.0]  # XY geometry padded with z = 0

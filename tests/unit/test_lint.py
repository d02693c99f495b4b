"""Pyflakes' checks over the package, the scripts and the tests (``ruff check``, rules in
pyproject.toml): an undefined name is a NameError waiting in whichever branch runs it first.
Measured: snow's peridynamic stress lost its numpy import in a refactor, and only a script's
smoke run (SPB-MPM of a snow bar) reached that line; this check names it at once."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_pyflakes_finds_nothing():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache",
                             "--output-format", "concise", "hpcmpm", "scripts", "tests"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]

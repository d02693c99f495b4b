"""The numba cache directory is keyed on the package's sources, so a change in a helper that a
kernel inlines from another module cannot leave stale machine code in use."""

import os
import subprocess
import sys

from hpcmpm import numba_cache


def test_fingerprint_follows_the_sources(tmp_path, monkeypatch):
    package = tmp_path / "pkg"
    (package / "kernels").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    helper = package / "kernels" / "shape.py"
    helper.write_text("A = 1\n")
    monkeypatch.setattr(numba_cache, "PACKAGE", package)
    first = numba_cache.source_fingerprint()
    assert first == numba_cache.source_fingerprint()  # deterministic
    helper.write_text("A = 2\n")
    assert numba_cache.source_fingerprint() != first


def test_cli_sets_the_cache_before_numba_is_imported(tmp_path):
    """`hpcmpm run` without NUMBA_CACHE_DIR compiles into XDG_CACHE_HOME/hpcmpm/numba/<fp>:
    numba reads the variable at import, so setting it any later would be ignored."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    script = ("import os, sys; from hpcmpm import cli; "
              "sys.argv = ['hpcmpm', 'run', 'inputs/dam_break_2d.toml', '--out', "
              f"{str(tmp_path / 'out')!r}, '--quiet', '--set', 'simulation.end_time=0.002']; "
              "code = cli.main(); import numba; "
              "print('CACHE', numba.config.CACHE_DIR); sys.exit(code)")
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    expected = tmp_path / "cache" / "hpcmpm" / "numba" / numba_cache.source_fingerprint()
    assert f"CACHE {expected}" in proc.stdout
    assert any(expected.rglob("*.nbi"))  # the kernels were cached there

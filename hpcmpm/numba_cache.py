"""Where numba keeps the compiled kernels: one directory shared by all ranks, per source tree.

numba keys a kernel's cache entry on its own source file only, so a kernel that inlines a
helper from another module (`kernels.shape.weights`, `kernels.deformation`, the small-tensor
algebra) would keep running stale machine code after the helper changed. Keying the directory
on a fingerprint of every source file of the package makes any change start from an empty
cache (one cold compile) instead.

This module imports nothing heavy: `configure` must run before numba is imported, because numba
reads ``NUMBA_CACHE_DIR`` once, at import.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


def source_fingerprint() -> str:
    """12 hex digits of a hash over the package's Python sources (paths and contents)."""
    digest = hashlib.sha1()
    for path in sorted(PACKAGE.rglob("*.py")):
        digest.update(str(path.relative_to(PACKAGE)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def configure() -> str:
    """Set ``NUMBA_CACHE_DIR`` (unless the user did) to ``~/.cache/hpcmpm/numba/<fingerprint>``
    and return it. Call before anything imports numba."""
    if not os.environ.get("NUMBA_CACHE_DIR"):
        root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        os.environ["NUMBA_CACHE_DIR"] = str(root / "hpcmpm" / "numba" / source_fingerprint())
    return os.environ["NUMBA_CACHE_DIR"]

"""`hpcmpm bench`: run the benchmark scripts of a source checkout.

The benchmarks live in ``scripts/bench_*.py`` (they are studies, not part of the package, and
the peer comparison needs the ``bench`` extra: taichi, matplotlib). ``hpcmpm bench WHAT
[ARGS...]`` runs ``scripts/bench_WHAT.py ARGS...`` in a subprocess with this interpreter, from
the repository root; ``hpcmpm bench all`` runs every one in turn with the given ARGS (e.g.
``--smoke``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from .errors import HpcmpmError

BENCHMARKS = {
    "peer": "throughput against Taichi's MLS-MPM (CPU, float64), scenes a, a_fc, b",
    "ceiling": "throughput against a minimal fused numba MLS-MPM step",
    "parallel": "scene b on 1 and 2 MPI ranks: parallel efficiency",
    "memory": "bytes per particle (fields and peak RSS), elastic and snow, 2D and 3D",
    "startup": "process start to first step, cold and warm numba cache",
    "semi_implicit": "explicit vs semi-implicit time to solution, CG iterations (Jacobi/none), "
                     "Hessian-vector product vs explicit transfers",
    "plots": "PNG plots of bench_results/*.json into docs/img/",
}


def scripts_dir() -> Path:
    """``scripts/`` of the checkout this package was installed from (editable install)."""
    return Path(__file__).resolve().parents[1] / "scripts"


def usage() -> str:
    rows = "\n".join(f"  {name:<13} {doc}" for name, doc in BENCHMARKS.items())
    return (f"usage: hpcmpm bench {{{','.join(BENCHMARKS)},all}} [ARGS...]\n{rows}\n"
            f"  all       every benchmark above, each with ARGS\n"
            f"ARGS go to the script; `hpcmpm bench peer --help` lists them.")


def bench_command(args) -> int:
    """Dispatch ``args.bench_args`` (the argv after ``bench``) to ``scripts/bench_*.py``;
    returns the exit code."""
    argv = list(getattr(args, "bench_args", None) or [])
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0 if argv else 2
    what, rest = argv[0], argv[1:]
    if what != "all" and what not in BENCHMARKS:
        raise HpcmpmError(f"bench: unknown benchmark {what!r}; choose one of "
                          f"{', '.join(BENCHMARKS)}, all")
    folder = scripts_dir()
    names = [n for n in BENCHMARKS if n != "plots"] if what == "all" else [what]
    missing = [n for n in names if not (folder / f"bench_{n}.py").exists()]
    if missing:
        raise HpcmpmError(f"bench: {folder} has no bench_{missing[0]}.py; the benchmarks run "
                          f"from a source checkout (pip install -e '.[bench]')")
    code = 0
    for name in names:
        result = subprocess.run([sys.executable, str(folder / f"bench_{name}.py"), *rest],
                                cwd=folder.parent)
        code = code or result.returncode
    return code

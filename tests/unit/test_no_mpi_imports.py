"""One MPI seam: only hpcmpm/parallel/ may import mpi4py (STYLE.md)."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "hpcmpm"


def mpi_imports(path: Path) -> list[int]:
    """Line numbers of `import mpi4py...` / `from mpi4py... import ...` anywhere in the file
    (function-local imports included)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            if any(a.name == "mpi4py" or a.name.startswith("mpi4py.") for a in node.names):
                lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "mpi4py" or node.module.startswith("mpi4py."):
                lines.append(node.lineno)
    return lines


def test_only_parallel_imports_mpi4py():
    parallel = PACKAGE / "parallel"
    offenders = [f"{path.relative_to(PACKAGE.parent)}:{line}"
                 for path in sorted(PACKAGE.rglob("*.py")) if parallel not in path.parents
                 for line in mpi_imports(path)]
    assert not offenders, "mpi4py imported outside hpcmpm/parallel/: " + ", ".join(offenders)


def test_the_scan_sees_an_import(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from mpi4py import MPI\n    import mpi4py.util\n")
    assert mpi_imports(probe) == [2, 3]

#!/usr/bin/env bash
# Create (or reuse) the project's virtual environment and install hpcmpm into it.
#   bash scripts/install.sh [EXTRAS]      e.g. EXTRAS=test  -> pip install -e '.[mpich,viz,test]'
# Needs only python3 (3.11+) with venv; no root. MPI comes from the PyPI `mpich` wheel.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${HPCMPM_VENV:-$root/.venv}"
extras="mpich,viz${1:+,$1}"  # viz: ffmpeg for hpcmpm render's MP4 movies
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip >/dev/null 2>&1 || true
log="$(mktemp)"
if ! "$venv/bin/python" -m pip install --quiet -e "$root[$extras]" >"$log" 2>&1; then
    cat "$log" >&2; exit 1
fi
rm -f "$log"
echo "$venv"

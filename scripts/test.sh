#!/usr/bin/env bash
# Install hpcmpm with its test extras into .venv and run the whole test suite (serial and MPI).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/install.sh" test >/dev/null
. "$root/scripts/env.sh"
cd "$root"
exec python -m pytest -q "$@"

# Source this to run hpcmpm from the project's virtual environment:  . scripts/env.sh
_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PATH="${HPCMPM_VENV:-$_root/.venv}/bin:$PATH"
# One numba thread per MPI rank: ranks already fill the cores.
export NUMBA_NUM_THREADS="${NUMBA_NUM_THREADS:-1}"
# A cache shared by all ranks, so a second run does not recompile.
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$_root/.numba_cache}"
unset _root

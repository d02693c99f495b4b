# Source this to run hpcmpm from the project's virtual environment:  . scripts/env.sh
_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PATH="${HPCMPM_VENV:-$_root/.venv}/bin:$PATH"
# One numba thread per MPI rank: ranks already fill the cores.
export NUMBA_NUM_THREADS="${NUMBA_NUM_THREADS:-1}"
# A cache shared by all ranks, so a second run does not recompile; one directory per state of
# the sources, because numba does not notice a change in a helper that a kernel inlines from
# another module (hpcmpm/numba_cache.py).
_fingerprint="$(cd "$_root" && find hpcmpm -name '*.py' | LC_ALL=C sort | xargs cat | sha1sum | cut -c1-12)"
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$_root/.numba_cache/$_fingerprint}"
unset _root _fingerprint

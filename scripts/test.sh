#!/usr/bin/env bash
# Install hpcmpm with its test extras into .venv and run the whole test suite (serial and MPI).
# Then, where the machine allows it (root + apt-get), build a second environment with parallel
# HDF5 (.venv-mpio, scripts/setup_parallel_hdf5.sh) and run the I/O tests again in mpio mode.
#   bash scripts/test.sh                 everything
#   bash scripts/test.sh tests/unit      a subset (skips the parallel-HDF5 pass)
#   HPCMPM_SKIP_MPIO=1 bash scripts/test.sh
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# bench brings the Taichi peer, so the benchmark smoke tests run against it too.
bash "$root/scripts/install.sh" test,bench >/dev/null
cd "$root"
# Real ParaView opens the XDMF output in tests/unit/test_io_paraview.py where it can be
# installed (root + apt-get; about 1 minute); elsewhere that test is skipped with its reason.
if ! command -v pvpython >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        --no-install-recommends paraview python3-paraview xvfb xauth) >/dev/null 2>&1 \
        || echo "ParaView not installable here; its check is skipped"
fi
(. scripts/env.sh && python -m pytest -q "$@")
if [ $# -gt 0 ] || [ "${HPCMPM_SKIP_MPIO:-0}" = 1 ]; then
    exit 0
fi
bash scripts/setup_parallel_hdf5.sh
if [ -x .venv-mpio/bin/python ] && .venv-mpio/bin/python -c \
        "import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)" 2>/dev/null; then
    echo "== I/O tests again with parallel HDF5 (mpio mode) =="
    (HPCMPM_VENV="$root/.venv-mpio" . scripts/env.sh && \
        python -m pytest -q tests/mpi/test_io_modes.py tests/unit/test_io_frames.py \
            tests/unit/test_io_checkpoint.py)
fi

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
. scripts/apt.sh
# Where root and apt-get allow (elsewhere these tests are skipped with their reason): real
# ParaView opens and renders the XDMF output under xvfb (tests/unit/test_io_paraview.py; about
# 1 minute), and a private one-node SLURM runs the rendered job script
# (tests/mpi/test_slurm_cluster.py; Debian's SLURM 22.05 and munge, about 10 s). A failed
# install prints apt-get's own words.
if ! command -v pvpython >/dev/null 2>&1 || ! command -v xvfb-run >/dev/null 2>&1; then
    apt_install ParaView paraview python3-paraview xvfb xauth || true
fi
if ! command -v slurmctld >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
    apt_install SLURM slurmctld slurmd slurm-client munge || true
fi
# -rs (also in pyproject's addopts): every skipped test is listed with its reason.
(. scripts/env.sh && python -m pytest -q -rs "$@")
if [ $# -gt 0 ] || [ "${HPCMPM_SKIP_MPIO:-0}" = 1 ]; then
    exit 0
fi
# Where root and apt-get allow the parallel-HDF5 build, its failure fails this command (set -e);
# elsewhere the script says why there is no mpio pass and exits 0.
bash scripts/setup_parallel_hdf5.sh
if apt_allowed || [ -x .venv-mpio/bin/python ]; then
    .venv-mpio/bin/python -c "import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)" \
        || { echo "error: .venv-mpio has no MPI-enabled h5py after setup_parallel_hdf5.sh"; exit 1; }
    echo "== I/O tests again with parallel HDF5 (mpio mode) =="
    (HPCMPM_VENV="$root/.venv-mpio" . scripts/env.sh && \
        python -m pytest -q -rs tests/mpi/test_io_modes.py tests/unit/test_io_frames.py \
            tests/unit/test_io_checkpoint.py)
fi

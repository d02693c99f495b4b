#!/usr/bin/env bash
# Install hpcmpm with its test extras into .venv and run the whole test suite (serial and MPI).
# Where the machine allows it (root + apt-get), a second environment with parallel HDF5
# (.venv-mpio, scripts/setup_parallel_hdf5.sh) is built meanwhile, in the background (its log:
# .mpio-setup.log), and the I/O tests then run again in mpio mode.
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
# The parallel-HDF5 environment for the second pass is built while the main suite runs: its
# compiles (mpi4py and h5py from source, about 13 minutes on 2 cores) are single-threaded and
# would otherwise add their whole time to the suite's; at the lowest priority they take the core
# the suite leaves idle (most of it runs in one process) and yield it to the MPI tests.
mpio=0
if [ $# -eq 0 ] && [ "${HPCMPM_SKIP_MPIO:-0}" != 1 ]; then
    mpio=1
    mpio_log="$root/.mpio-setup.log"
    setsid nice -n 19 bash scripts/setup_parallel_hdf5.sh >"$mpio_log" 2>&1 &
    mpio_pid=$!
    # A failed suite ends this script (set -e): stop the build with it.
    trap 'kill -- -"$mpio_pid" 2>/dev/null || true' EXIT
fi
# -rs (also in pyproject's addopts): every skipped test is listed with its reason.
if [ $# -gt 0 ]; then
    (. scripts/env.sh && python -m pytest -q -rs --durations=30 "$@")
else
    # The whole suite: the single-process tests first, on two pytest-xdist workers (they
    # compile the numba kernels into the shared cache, where the MPI tests, first in
    # pytest's own order, had every rank of a launch compile the same kernels at once), then
    # the MPI tests, whose launches use both cores themselves. Both parts always run.
    status=0
    (. scripts/env.sh && python -m pytest -q -rs --durations=30 -n 2 tests/unit \
        tests/verification) || status=$?
    (. scripts/env.sh && python -m pytest -q -rs --durations=30 tests/mpi) || status=$?
    [ "$status" = 0 ] || exit "$status"
fi
[ "$mpio" = 1 ] || exit 0
echo "== parallel HDF5 environment (scripts/setup_parallel_hdf5.sh, built during the suite) =="
# Where root and apt-get allow the parallel-HDF5 build, its failure fails this command;
# elsewhere the script says why there is no mpio pass and exits 0.
status=0
wait "$mpio_pid" || status=$?
trap - EXIT
grep -v "^WARNING: Location" "$mpio_log" || true
[ "$status" = 0 ] || { echo "error: scripts/setup_parallel_hdf5.sh failed (exit $status)"; exit 1; }
if apt_allowed || [ -x .venv-mpio/bin/python ]; then
    .venv-mpio/bin/python -c "import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)" \
        || { echo "error: .venv-mpio has no MPI-enabled h5py after setup_parallel_hdf5.sh"; exit 1; }
    echo "== I/O tests again with parallel HDF5 (mpio mode) =="
    (HPCMPM_VENV="$root/.venv-mpio" . scripts/env.sh && \
        python -m pytest -q -rs tests/mpi/test_io_modes.py tests/unit/test_io_frames.py \
            tests/unit/test_io_checkpoint.py)
fi

#!/usr/bin/env bash
# Set up a second virtual environment, .venv-mpio, whose h5py writes with MPI-IO (parallel HDF5).
#
#   bash scripts/setup_parallel_hdf5.sh            # then:  HPCMPM_VENV=$PWD/.venv-mpio . scripts/env.sh
#
# The default environment (.venv, scripts/install.sh) uses PyPI wheels only: MPICH from the
# `mpich` wheel and a serial h5py, so rank 0 writes every file. Parallel HDF5 needs an HDF5 built
# against the same MPI that mpi4py and h5py link, which on Debian means root + apt-get:
#   Debian's MPICH + libhdf5-mpich-dev, then mpi4py and h5py compiled from source against them
#   (docs/output.md, "Parallel HDF5"). About 6 minutes on 2 cores the first time (mpi4py ~3 min,
#   h5py ~3 min); pip caches the built wheels, so a rerun is fast.
# Without root or apt-get it prints "parallel HDF5 not available; serial mode only" and exits 0:
# hpcmpm then writes in serial mode, which is always correct. Where root and apt-get are there,
# any failure (apt-get, a build) is an error: it prints what failed and exits 1.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${HPCMPM_MPIO_VENV:-$root/.venv-mpio}"
python="${PYTHON:-python3}"
hdf5_dir=/usr/lib/x86_64-linux-gnu/hdf5/mpich

unavailable() {
    echo "parallel HDF5 not available; serial mode only ($1)"
    exit 0
}

failed() {
    echo "[setup_parallel_hdf5] error: $1" >&2
    exit 1
}

. "$root/scripts/apt.sh"
[ "$(id -u)" = 0 ] || unavailable "needs root for apt-get"
command -v apt-get >/dev/null 2>&1 || unavailable "no apt-get on this machine"

t0=$SECONDS
echo "[setup_parallel_hdf5] apt-get: mpich libmpich-dev libhdf5-mpich-dev pkg-config"
apt_install "parallel HDF5" mpich libmpich-dev libhdf5-mpich-dev pkg-config \
    || failed "apt-get could not install Debian's MPICH and parallel HDF5 (see above)"
[ -d "$hdf5_dir" ] || failed "no HDF5 tree at $hdf5_dir after installing libhdf5-mpich-dev"
echo "[setup_parallel_hdf5] apt done in $((SECONDS - t0)) s"

# Call the .mpich names explicitly: with Open MPI also installed, plain mpicc may be Open MPI's.
export CC=mpicc.mpich
export MPICC=mpicc.mpich

if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip install --quiet)
"${pip[@]}" --upgrade pip >/dev/null 2>&1 || true
# Build requirements first, then --no-build-isolation: with isolation pip recompiles mpi4py
# inside the isolated build environment (one compiler process ran > 17 min and 3.7 GB).
"${pip[@]}" numpy Cython pkgconfig "setuptools>=77" wheel

t1=$SECONDS
echo "[setup_parallel_hdf5] building mpi4py against Debian's MPICH (a few minutes)"
# mpi4py from source, so no LD_LIBRARY_PATH trick is needed at run time (the PyPI binary wheel
# links libmpi.so.12, which Debian's MPICH does not ship: it has libmpich.so.12 only).
"${pip[@]}" --no-build-isolation --no-binary=mpi4py "mpi4py>=4.0"
echo "[setup_parallel_hdf5] mpi4py done in $((SECONDS - t1)) s"

t2=$SECONDS
echo "[setup_parallel_hdf5] building h5py with HDF5_MPI=ON (a few minutes)"
HDF5_MPI=ON HDF5_DIR="$hdf5_dir" "${pip[@]}" --no-build-isolation --no-binary=h5py h5py
echo "[setup_parallel_hdf5] h5py done in $((SECONDS - t2)) s"

# hpcmpm itself, editable, with the test extras; mpi4py and h5py are already satisfied, so pip
# keeps the MPI builds. No `mpich` extra: this environment uses Debian's mpiexec.mpich.
"${pip[@]}" -e "$root[test]"

"$venv/bin/python" - <<'EOF'
import h5py, mpi4py
from mpi4py import MPI
assert h5py.get_config().mpi, "h5py was built without MPI"
print("[setup_parallel_hdf5] h5py", h5py.__version__, "mpi:", h5py.get_config().mpi,
      "| MPI:", MPI.Get_library_version().splitlines()[0])
EOF
# `mpiexec` inside the venv runs Debian's mpiexec.mpich, so `. scripts/env.sh` picks the
# launcher that matches the libraries. A wrapper, not a symlink: hydra looks for its
# hydra_pmi_proxy next to the path it was started from.
rm -f "$venv/bin/mpiexec"
printf '#!/bin/sh\nexec %s "$@"\n' "$(command -v mpiexec.mpich)" > "$venv/bin/mpiexec"
chmod +x "$venv/bin/mpiexec"

echo "[setup_parallel_hdf5] ready in $((SECONDS - t0)) s: $venv"
cat <<EOF
Use it:
  HPCMPM_VENV=$venv . $root/scripts/env.sh
  mpiexec -n 4 hpcmpm run SCENE.toml          # frames and checkpoints written with driver="mpio"
  mpiexec -n 2 python -m mpi4py -m pytest tests/mpi/test_io_modes.py
EOF

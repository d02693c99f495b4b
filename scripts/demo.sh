#!/usr/bin/env bash
# Install hpcmpm into .venv, run the demo scene on 2 MPI ranks, render it (PNGs + a movie) on
# 2 ranks; prints where the output went and, last, the path of the movie.
#   bash scripts/demo.sh [SCENE]     (default inputs/disks_2d.toml)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/install.sh" >/dev/null
. "$root/scripts/env.sh"
cd "$root"
scene="${1:-inputs/disks_2d.toml}"
out="runs/$(basename "$scene" .toml)"
mpiexec -n 2 hpcmpm run "$scene" --out "$out" --force
mpiexec -n 2 hpcmpm render "$out" --quiet

#!/usr/bin/env bash
# README command 1: set up (idempotent), then the main job on the built-in default bed:
# the paper's figure-2 bed (0.25 mm x 0.25 mm x 0.1 mm) generated, homogenized on 2 MPI
# ranks with CG + GAMG, the constants printed, JSON and ParaView files written to results/.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/run/setup.sh"
source "$root/run/env.sh"
cd "$root"
out="${AMFE_RESULTS:-results}"
mkdir -p "$out"
.venv/bin/amfe pack -o "$out/bed.h5" --seed 0
mpirun -n 2 .venv/bin/amfe homogenize "$out/bed.h5" -o "$out/result.json" --vtu "$out/vtu" "$@"
echo "Open $out/vtu/cases.pvd in ParaView to see the six deformed frames."

#!/usr/bin/env bash
# README command 1: set up (idempotent), then the main job on the built-in default bed:
# the paper's figure-2 bed (0.25 mm x 0.25 mm x 0.1 mm) generated, homogenized on 2 MPI
# ranks with CG + GAMG, the constants printed, JSON and ParaView files written to results/,
# a PNG of load case xx rendered;
# then the surrogate's prediction for a `small` bed beside the solver's result.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/run/setup.sh"
source "$root/run/env.sh"
cd "$root"
out="${AMFE_RESULTS:-results}"
mkdir -p "$out"
.venv/bin/amfe pack -o "$out/bed.h5" --seed 0
mpirun -n 2 .venv/bin/amfe homogenize "$out/bed.h5" -o "$out/result.json" --vtu "$out/vtu" "$@"
# A picture of load case xx (ParaView's pvpython when installed, else matplotlib); it
# prints the warp factor and the PNG's path. docs/viewing.md: the other cases, ParaView.
.venv/bin/amfe view "$out/vtu" --case xx
echo "Open $out/vtu/cases.pvd in ParaView to see the six deformed frames (docs/viewing.md)."
# The bounds report (docs/model.md, section 9): KUBC beside SUBC on the periodic twin of the
# bed, and the periodic value, the material's own stiffness, with their gaps.
.venv/bin/amfe pack -o "$out/bed_periodic.h5" --seed 0 --periodic
mpirun -n 2 .venv/bin/amfe homogenize "$out/bed_periodic.h5" --bc all --quiet -o "$out/bounds.json"
# The model level (docs/model.md, section 10): the paper's springs against the continuum of the
# same spheres on this bed, one line from the stored measurement (no voxel solve here).
.venv/bin/python -m run.report.voxel_model_error --headline
# The CNN surrogate shipped in amfe/models/ on a bed of the scale it was trained on
# (0.6 x 0.6 x 0.3 mm), printed beside the PETSc solve of the same bed (--check). The bed
# is record 0 of the held-out test set of docs/surrogate.md (data-set seed 2), which no
# member trained on.
.venv/bin/amfe pack -o "$out/small_bed.h5" --scale small --seed 2834126987
mpirun -n 2 .venv/bin/amfe predict "$out/small_bed.h5" --check -o "$out/prediction.json"

"""Issue 33's gates as a user meets them: `mpirun -n 2 amfe homogenize BED.h5 -o R.json` per bed.

    python -m run.bench.gates BED.h5 [BED.h5 ...] [--variants new,old] [--reference N]
                              [--full] [--ranks 2]

Each bed runs through the command line (start-up, reading, frame, solve and
the JSON included), interleaved per bed, once per variant:

- new: the defaults (the per-bed multigrid, amfe.solvers.mgchoice: beds with
  free hull vertices get smoothed aggregation, and rtol 1e-5 where those
  vertices carry little of the strain, amfe.solvers.correction.FREE_SHARE_MAX,
  else 1e-7);
- rtol7: the defaults before that share rule, on a first-order bed (--rtol 1e-7:
  the same multigrid);
- old: the defaults before issue 33 (-pc_gamg_agg_nsmooths 0);
- adjoint: the strain's adjoints on beds with free hull vertices
  (-amfe_strain_adjoint yes, amfe.solvers.adjoint: rtol 1e-5, and then the
  choice's unsmoothed aggregation);
- adjoint_smoothed: the same with smoothed aggregation forced.

Printed per bed and variant: wall [s], CG iterations of the six cases (and of
the adjoints), rtol, and with --reference N (the first N beds) the largest
relative error of the nine constants against --rtol 1e-10. --full also times
`amfe pack -o full.h5 --size 3 3 0.3 --seed 1` followed by
`amfe homogenize full.h5 -o r.json --quiet`, as a user runs them, per variant.
Only ratios within one run hold on a loaded machine (docs/benchmarks.md,
"Issue 33's gates").
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from run.common import parser

VARIANTS = {
    "new": [],
    "rtol7": ["--rtol", "1e-7"],
    "old": ["-pc_gamg_agg_nsmooths", "0", "-amfe_strain_adjoint", "no"],
    "adjoint": ["-amfe_strain_adjoint", "yes"],
    "adjoint_smoothed": ["-amfe_strain_adjoint", "yes", "-pc_gamg_agg_nsmooths", "1",
                         "-mg_levels_ksp_max_it", "2"],
}
REFERENCE = ["--rtol", "1e-10"]


def amfe(ranks, *args):
    """Wall [s] of `mpirun -n ranks python -m amfe args` (ranks None: no mpirun); a failure stops
    the benchmark."""
    cmd = (["mpirun", "-n", str(ranks)] if ranks else []) + [sys.executable, "-m", "amfe", *args]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode:
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    return wall


def homogenize(bed, out, ranks, extra):
    wall = amfe(ranks, "homogenize", bed, "-o", out, "--quiet", *extra)
    with open(out) as f:
        return wall, json.load(f)


def error(res, ref):
    """Largest relative difference of the nine constants."""
    return max(abs(res["properties"][k] / v - 1) for k, v in ref["properties"].items())


def row(name, wall, res, ref):
    s = res["solver"]
    adj = s.get("adjoint_iterations")
    err = f"{error(res, ref):.1e}" if ref is not None else "-"
    return (f"  {name:16s} wall {wall:6.1f} s  rtol {s['rtol']:.0e}  its {min(s['iterations'])}-"
            f"{max(s['iterations'])}" + (f" + adjoints {min(adj)}-{max(adj)}" if adj else "")
            + f"  set-up {s['setup_seconds']:.1f} s  solves {s['solve_seconds']:.1f} s"
            + (f" + {s['adjoint_seconds']:.1f} s" if adj else "") + f"  err {err}")


def main():
    ap = parser(__doc__)
    ap.add_argument("beds", nargs="*")
    ap.add_argument("--variants", default="new,old")
    ap.add_argument("--reference", type=int, default=0, metavar="N")
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--ranks", type=int, default=2)
    a = ap.parse_args()
    names = a.variants.split(",")
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        sys.exit(f"bench_gates: unknown variant(s) {unknown}: choose from {list(VARIANTS)}")
    print(f"{a.ranks} ranks; load average at start {os.getloadavg()[0]:.1f}", flush=True)
    walls = {n: [] for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "r.json")
        for b, bed in enumerate(a.beds):
            ref = homogenize(bed, out, a.ranks, REFERENCE)[1] if b < a.reference else None
            print(bed, flush=True)
            for n in names:
                wall, res = homogenize(bed, out, a.ranks, VARIANTS[n])
                walls[n].append(wall)
                print(row(n, wall, res, ref), flush=True)
            print("  " + "  ".join(f"{n}/{names[-1]} {walls[n][-1] / walls[names[-1]][-1]:.2f}"
                                   for n in names[:-1]), flush=True)
        if a.beds:
            print("median wall: " + "  ".join(f"{n} {np.median(w):.1f} s" for n, w in walls.items()))
        if a.full:
            full = os.path.join(tmp, "full.h5")
            for n in names:
                t0 = time.perf_counter()
                amfe(None, "pack", "-o", full, "--size", "3", "3", "0.3", "--seed", "1")
                t_pack = time.perf_counter() - t0
                wall, res = homogenize(full, out, a.ranks, VARIANTS[n])
                print(f"whole bed, {n}: pack + homogenize {t_pack + wall:.1f} s "
                      f"(pack {t_pack:.1f} s)", flush=True)
                print(row(n, wall, res, None), flush=True)
                os.remove(full)


if __name__ == "__main__":
    main()

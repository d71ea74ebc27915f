"""Scanned beds: the per-bed multigrid choice (amfe.solvers.mgchoice) against the old defaults.

    mpirun -n 2 python -m run.bench.scanned BED.h5 [BED.h5 ...] [--repeat R] [--reference]

Per bed, interleaved R times: "old" (-pc_gamg_agg_nsmooths 0, the block path's former
default for every bed), "new" (the defaults: the choice per bed) and "smoothed"
(-pc_gamg_agg_nsmooths 1 and the Galerkin algorithm the choice sets, on every bed:
what smoothing would cost where the choice keeps unsmoothed aggregation). Prints iterations,
set-up, the six solves and wall, the ratios new/old, and with --reference the largest
relative error of the nine constants of each against CG + GAMG at rtol 1e-10.
Only the ratios hold on a loaded machine (docs/benchmarks.md, "Multigrid per bed").
"""
import argparse
import time

import numpy as np
from mpi4py import MPI

from amfe import homogenize, read_bed
from amfe.solvers.blocksolve import galerkin_algorithm
from run.common import parser


def run(bed, ksp_options, rtol=None):
    t0 = time.perf_counter()
    r = homogenize(bed, rtol=rtol, petsc_options=ksp_options)
    wall = time.perf_counter() - t0
    return r, wall


def props(r):
    return np.array(list(r.properties.values()), dtype=float) if isinstance(r.properties, dict) \
        else np.asarray(r.properties, dtype=float)


def main():
    ap = parser(__doc__)
    ap.add_argument("beds", nargs="+")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--reference", action="store_true")
    a = ap.parse_args()
    root, size = MPI.COMM_WORLD.rank == 0, MPI.COMM_WORLD.size
    for path in a.beds:
        bed = read_bed(path)
        ref = run(bed, {}, rtol=1e-10)[0] if a.reference else None
        rows = {"old": [], "new": [], "smoothed": []}
        for _ in range(a.repeat):
            for name, opts in (("old", {"pc_gamg_agg_nsmooths": "0"}), ("new", {}),
                               ("smoothed", {"pc_gamg_agg_nsmooths": "1",
                                             "matptap_via": galerkin_algorithm(size)})):
                r, wall = run(bed, opts)
                s = r.solver
                err = (np.max(np.abs(props(r) - props(ref)) / np.abs(props(ref)))
                       if ref is not None else float("nan"))
                rows[name].append((min(s["iterations"]), max(s["iterations"]),
                                   sum(s["setup_seconds"]) if isinstance(s["setup_seconds"], list)
                                   else s["setup_seconds"],
                                   sum(s["solve_seconds"]) if isinstance(s["solve_seconds"], list)
                                   else s["solve_seconds"], wall, err,
                                   s.get("multigrid", {}).get("reason", "")))
        if root:
            print(path)
            for name, rs in rows.items():
                for it0, it1, su, so, w, e, why in rs:
                    print(f"  {name}: its {it0}-{it1}  setup {su:.2f} s  solves {so:.2f} s  "
                          f"wall {w:.2f} s  err {e:.1e}  {why if name == 'new' else ''}")
            med = {k: np.median([x[2:5] for x in v], axis=0) for k, v in rows.items()}
            for name in ("new", "smoothed"):
                q = med[name] / med["old"]
                print(f"  {name}/old: setup {q[0]:.2f}  solves {q[1]:.2f}  wall {q[2]:.2f}")


if __name__ == "__main__":
    main()

"""Solver benchmark (issue 3): phase times, GAMG iterations and direct solvers, per bed size.

    python -m run.bench.solver                      # ~1k, ~13k, ~116k particles
    python -m run.bench.solver --paper              # + the paper's 3 mm x 3 mm x 0.3 mm bed
    mpirun -n 2 python -m run.bench.solver --paper --no-direct

Prints one table row per bed and solver: seconds for generation, bonds
(frame), assembly, preconditioner/factor set-up, each of the six solves and
the averaging; iterations; and the max relative difference of the nine
constants against the CG+GAMG result at rtol 1e-8 (the speed claims' error).
Direct solvers: PETSc Cholesky with MUMPS (every rank count) and scipy SuperLU
(serial runs only), on every bed up to --direct-max particles. A line with and
without the non-dimensionalisation shows what the scaling buys.
"""
import argparse
import time


import numpy as np  # noqa: E402

from amfe.solvers.petsc import init_petsc  # noqa: E402
from run.common import parser

BEDS = {  # name: box size [mm], fully scanned HCP
    "1k": (0.3, 0.3, 0.1),
    "13k": (0.7, 0.7, 0.25),
    "116k": (1.6, 1.6, 0.4),
    "paper": (3.0, 3.0, 0.3),
}
MUMPS = {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"}


def main():
    ap = parser(__doc__)
    ap.add_argument("--beds", default="1k,13k,116k", help="comma list of " + ",".join(BEDS))
    ap.add_argument("--paper", action="store_true", help="add the paper's full bed")
    ap.add_argument("--direct-max", type=int, default=130_000,
                    help="largest bed (particles) given to the direct solvers")
    ap.add_argument("--no-direct", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    args, petsc_args = ap.parse_known_args()
    PETSc = init_petsc(petsc_args)
    from amfe.model.bed import generate_bed
    from amfe.model.frame import build_frame
    from amfe.solvers.driver import homogenize_bed
    from amfe.model.options import SolveOptions
    from amfe.solvers.scipy_direct import kubc_stiffness_scipy

    comm = PETSc.COMM_WORLD
    rank, size = comm.getRank(), comm.getSize()
    names = args.beds.split(",") + (["paper"] if args.paper else [])

    def out(*a):
        if rank == 0:
            print(*a, flush=True)

    out(f"# amfe solver benchmark: {size} rank(s), PETSc {'.'.join(map(str, PETSc.Sys.getVersion()))}")
    out(f"{'bed':>6} {'particles':>9} {'bonds':>8} {'solver':<18} {'gen':>6} {'frame':>6} "
        f"{'asm':>6} {'setup':>7} {'solve/case':>10} {'avg':>6} {'total':>7} {'its':>5} {'max rel err':>11}")
    for name in names:
        t0 = time.perf_counter()
        bed = generate_bed(size=tuple(v * 1e-3 for v in BEDS[name]), seed=args.seed)
        t_gen = time.perf_counter() - t0
        runs = [("cg+gamg", {}, True)]
        if not args.no_direct and len(bed) <= args.direct_max:
            runs.append(("cholesky mumps", MUMPS, True))
        if name in ("1k", "13k"):
            runs.append(("cg+gamg SI units", {}, False))
        ref = None
        for label, opts, nondim in runs:
            comm.barrier()
            t0 = time.perf_counter()
            try:
                r = homogenize_bed(bed, SolveOptions(solver="gamg", ksp_options=opts,
                                                     nondimensional=nondim)).to_dict()
            except Exception as exc:  # a benchmark row, not a crash
                out(f"{name:>6} {len(bed):9d} {'':>8} {label:<18} failed: {exc}")
                continue
            total = time.perf_counter() - t0 + t_gen
            s = r["solver"]
            ref = ref or r
            err = max(abs(r["properties"][k] / ref["properties"][k] - 1) for k in ref["properties"])
            its = max(s["iterations"])
            out(f"{name:>6} {len(bed):9d} {r['n_bonds']:8d} {label:<18} {t_gen:6.2f} "
                f"{s['frame_seconds']:6.2f} {s['assembly_seconds']:6.2f} {s['setup_seconds']:7.2f} "
                f"{np.mean(s['case_seconds']):10.3f} {s['average_seconds']:6.2f} {total:7.2f} "
                f"{its:5d} {err:11.2e}")
        if size == 1 and not args.no_direct and len(bed) <= min(args.direct_max, 20_000):
            frame = build_frame(bed.centers, bed.radii, size=bed.attrs.get("size"))
            t0 = time.perf_counter()
            C, sec = kubc_stiffness_scipy(frame)
            wall = time.perf_counter() - t0
            Cref = np.array(ref["C"]) / frame.stress_scale
            err = np.abs(C - Cref).max() / np.abs(Cref).max()
            out(f"{name:>6} {len(bed):9d} {'':>8} {'scipy superlu':<18} {t_gen:6.2f} {'':>6} "
                f"{sec['setup']:6.2f} {sec['factor']:7.2f} {sec['solve'] / 6:10.3f} {'':>6} "
                f"{wall + t_gen:7.2f} {'-':>5} {err:11.2e} (C)")
    out("setup = PC set-up (GAMG hierarchy) or factorisation; err against the first row of each bed.")


if __name__ == "__main__":
    main()

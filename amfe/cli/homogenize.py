"""`amfe homogenize BED.h5`: effective elastic constants of a bed, under mpirun too.

    mpirun -n 2 amfe homogenize bed.h5 -o result.json --vtu out/ -ksp_monitor -log_view

Rank 0 reads the bed and broadcasts it; every rank builds the same frame and
owns a block of its rows; rank 0 writes the JSON (atomically) and the VTU files.
"""
import os
import sys

from amfe.errors import AmfeError

PROPERTY_UNITS = [("Ex", "GPa"), ("Ey", "GPa"), ("Ez", "GPa"), ("nu_yz", ""), ("nu_xz", ""),
                  ("nu_xy", ""), ("G_yz", "GPa"), ("G_xz", "GPa"), ("G_xy", "GPa")]


def register(sub):
    p = sub.add_parser("homogenize", help="solve the six KUBC load cases of a bed (PETSc)",
                       description=__doc__.split("\n\n")[0],
                       epilog="Any -option (single dash) goes to PETSc, e.g. -ksp_monitor, "
                              "-log_view, -pc_type hypre.")
    p.add_argument("bed", help="bed HDF5 file (/particles/centers, /particles/radii)")
    p.add_argument("-o", "--output", help="write the result as JSON here")
    p.add_argument("--vtu", metavar="DIR", help="write the ParaView files here: case_<name>.vtp "
                   "per load case and cases.pvd (view them: amfe view DIR)")
    p.add_argument("--solver", choices=["auto", "gamg", "cholesky"], default="auto",
                   help="auto (default): Cholesky on one rank where its predicted fill is low, "
                        "else CG + GAMG; the constants stay within 1e-5 of a tight reference")
    p.add_argument("--rtol", type=float, default=None,
                   help="GAMG's relative tolerance (default 1e-8 with --solver gamg, 1e-7 "
                        "when auto picks GAMG)")
    p.add_argument("--cap-a-star", type=float, default=None, metavar="A",
                   help="evaluate bonds with a* > A at a* = A (A below the critical a*) "
                        "instead of refusing them; the JSON reports n_capped")
    p.add_argument("--bc", choices=["kubc", "mixed", "subc", "periodic", "all"], default="kubc",
                   help="kubc: six unit macro-strains on the boundary, one operator (default); "
                        "mixed: the paper's figure-2 experiments, prescribed displacements on "
                        "one pair of faces, traction-free elsewhere, six operators; subc: six "
                        "unit macro-stresses as loads on the boundary layer; periodic: a "
                        "periodic bed (amfe pack --periodic) on its torus; all: kubc and subc "
                        "(and periodic on a periodic bed) side by side with their gap")
    p.add_argument("--diagnose", action="store_true",
                   help="report per load case the iterations, true residual, eigenvalue "
                        "estimates of the preconditioned operator and GAMG complexities "
                        "(also in the JSON under 'diagnostics')")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (one per phase and load case)")
    p.set_defaults(func=run)


def run(args):
    from mpi4py import MPI

    from amfe.api import homogenize
    from amfe.cli.bounds import above_e_note
    from amfe.io.bedfile import read_bed
    from amfe.io.mpi import on_root
    from amfe.solvers.petsc import init_petsc

    init_petsc(args.petsc_args)
    comm = MPI.COMM_WORLD
    bed = on_root(comm, read_bed, args.bed)
    if args.rtol is not None and not (0 < args.rtol < 1):
        raise AmfeError(f"--rtol must lie in (0, 1), got {args.rtol}")
    if args.bc == "all":
        from amfe.cli.bounds import run_all
        return run_all(args, bed, comm, summary)
    result = homogenize(bed, comm=comm, a_star_cap=args.cap_a_star, rtol=args.rtol,
                        vtu_dir=args.vtu, bc=args.bc, diagnose=args.diagnose,
                        progress=not args.quiet, solver=args.solver, input_path=args.bed)
    if comm.rank == 0:
        if args.output:
            result.to_json(args.output)
        print(summary(result.to_dict(), args.bed, args.output, args.vtu))
        note = above_e_note(result.properties, bed.material().E)
        if note:
            print(note)
        sys.stdout.flush()
    return 0


def summary(result, bed_path, output=None, vtu=None):
    """A short human-readable table of a homogenization result."""
    s = result["solver"]
    lines = [f"{bed_path}: {result['n_particles']} particles ({result['n_removed']} removed, "
             f"not load-carrying), {result['n_bonds']} bonds, V = {result['volume']:.4g} m^3, "
             f"{result['ranks']} rank(s)",
             f"solver: {s['ksp_type']}+{s['pc_type']} rtol {s['rtol']:g}, iterations "
             f"{s['iterations']}, set-up {s['setup_seconds']:.3g} s, solves {s['solve_seconds']:.3g} s",
             f"boundary conditions: {result['bc']}; "
             + ", ".join(f"{k.replace('_', ' ')} {v:.1e}" for k, v in s.items()
                         if "asymmetry" in k or k.startswith("love_weber"))]
    if "n_capped" in result:
        lines.append(f"a* capped on {result['n_capped']} bonds")
    props = result["properties"]
    for key, unit in PROPERTY_UNITS:
        value = props[key] / 1e9 if unit == "GPa" else props[key]
        lines.append(f"  {key:6s} {value:12.6g} {unit}")
    if "diagnostics" in result:
        lines.append(diagnostics_table(result["diagnostics"]))
    if output:
        lines.append(f"wrote {output}")
    if vtu:
        lines.append(f"wrote {os.path.join(vtu, 'cases.pvd')} (6 load cases, per unit macro-strain)")
    return "\n".join(lines)


def diagnostics_table(diag):
    """Per-case solver diagnostics as text (see docs/diagnostics.md)."""
    lines = ["diagnostics (see docs/diagnostics.md):",
             f"  {'case':4s} {'its':>4s} {'true resid':>10s} {'eig min':>9s} {'eig max':>9s} "
             f"{'cond':>9s} {'grid cx':>7s} {'op cx':>6s}  levels"]
    for d in diag:
        def g(key, fmt):
            return format(d[key], fmt) if key in d else "-"
        lines.append(f"  {d['case']:4s} {d['iterations']:4d} {d['residual']:10.2e} "
                     f"{g('eig_min', '9.3g')} {g('eig_max', '9.3g')} {g('condition', '9.3g')} "
                     f"{g('grid_complexity', '7.3f')} {g('operator_complexity', '6.3f')}  "
                     f"{d.get('levels', '-')}")
    return "\n".join(lines)

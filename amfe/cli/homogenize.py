"""`amfe homogenize BED.h5`: effective elastic constants of a bed, under mpirun too.

    mpirun -n 2 amfe homogenize bed.h5 -o result.json --vtu out/ -ksp_monitor -log_view

Rank 0 reads the bed and broadcasts it; every rank builds the same frame and
owns a block of its rows; rank 0 writes the JSON (atomically) and the VTU files.
"""
import json
import os
import sys

from amfe.cli.options import (
    add_material_args,
    add_memory_arg,
    add_solver_args,
    given_material,
)
from amfe.errors import AmfeError
from amfe.io.units import length
from amfe.model.conditions import CONDITIONS

PROPERTY_UNITS = [("Ex", "GPa"), ("Ey", "GPa"), ("Ez", "GPa"), ("nu_yz", ""), ("nu_xz", ""),
                  ("nu_xy", ""), ("G_yz", "GPa"), ("G_xz", "GPa"), ("G_xy", "GPa")]


def register(sub):
    p = sub.add_parser("homogenize", help="solve the six KUBC load cases of a bed (PETSc)",
                       description=__doc__.split("\n\n")[0],
                       epilog="Any -option (single dash) goes to PETSc, e.g. -ksp_monitor, "
                              "-log_view, -pc_type hypre.")
    p.add_argument("bed", help="bed HDF5 file (/particles/centers, /particles/radii)")
    p.add_argument("-o", "--output",
                   help="write the result as JSON here (- : to stdout, the table to stderr)")
    p.add_argument("--vtu", metavar="DIR", help="write the ParaView files here: case_<name>.vtu "
                   "per load case, cases.json and cases.pvd (view them: amfe view DIR)")
    add_solver_args(p)
    p.add_argument("--box", nargs=3, type=length("m"), default=None, metavar=("LX", "LY", "LZ"),
                   help="V's box, m when bare, or with a unit (0.6mm 0.6mm 0.3mm): checked to "
                        "hold the load-carrying centres, centred on them (default: the bed "
                        "file's recorded size, else the load-carrying spheres' bounding box; "
                        "the result's volume_box says which)")
    p.add_argument("--cap-a-star", type=float, default=None, metavar="A",
                   help="evaluate bonds with a* > A at a* = A (A below the critical a*) "
                        "instead of refusing them; the JSON reports n_capped")
    p.add_argument("--bc", choices=[*CONDITIONS, "all"], default="kubc",
                   help="; ".join(f"{n}: {c.help}" for n, c in CONDITIONS.items())
                   + "; all: " + " and ".join(n for n, c in CONDITIONS.items()
                                               if c.in_all and not c.periodic)
                   + " (and the periodic ones on a periodic bed) side by side with their gap")
    p.add_argument("--diagnose", action="store_true",
                   help="report per load case the iterations, true residual, eigenvalue "
                        "estimates of the preconditioned operator and GAMG complexities "
                        "(also in the JSON under 'diagnostics')")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (one per phase and load case; above "
                        "50 000 particles also each phase's start and the time left); "
                        "warnings still print")
    p.add_argument("--accept-unconverged", action="store_true",
                   help="keep the constants of a solve whose true relative residual misses "
                        "10 x rtol (an error otherwise), with a warning in the JSON")
    add_material_args(p, "override the bed file's")
    add_memory_arg(p)
    # voxel model (issue 35; docs/model.md, section 10)
    p.add_argument("--model", choices=["frame", "voxel"], default="frame",
                   help="frame: the paper's bonded space frame (default); voxel: the continuum "
                        "of the same spheres by voxel finite elements (--bc kubc or periodic)")
    p.add_argument("--voxel-size", type=length("m"), default=None, metavar="H",
                   help="voxel side for --model voxel, m when bare, or with a unit (3um) "
                        "(default: mean radius / 4)")
    p.add_argument("--voxel-operator", choices=["assembled", "matrix-free"], default=None,
                   help="--model voxel's stiffness: assembled (AIJ + GAMG, default) or "
                        "matrix-free (elements on the fly, two-grid preconditioner: a few kB "
                        "a node instead of about 16)")
    p.set_defaults(func=run)


def run(args):
    from mpi4py import MPI

    from amfe.api import homogenize
    from amfe.cli.bounds import above_e_note
    from amfe.io.bedfile import read_bed
    from amfe.io.mpi import on_root
    from amfe.io.paths import check_output, check_output_dir, is_stdout
    from amfe.model.memory import parse_size
    from amfe.model.options import check_rtol
    from amfe.model.tolerance import check_command_rtol, given_rtol
    from amfe.solvers.petsc import init_petsc, option_pairs

    init_petsc(args.petsc_args)
    comm = MPI.COMM_WORLD

    def check_arguments():  # everything that can be refused, before reading or solving
        if args.voxel_operator and args.model != "voxel":
            raise AmfeError("--voxel-operator is an option of --model voxel")
        if args.rtol is not None:
            check_rtol(args.rtol, "--rtol")
        given = given_rtol(args.rtol, option_pairs(args.petsc_args))
        if len(given) == 1:   # the loosest rtol (issue 45); both given: the conflict's error
            check_command_rtol("homogenize", given[0][1], given[0][0])
        if args.output is not None:   # -o '' is an error, not "no output"
            check_output(args.output, inputs=[args.bed], allow_stdout=True)
        if args.vtu is not None:   # --vtu '' is an error too
            check_output_dir(args.vtu)
            from amfe.io.vtuset import check_outside_set
            check_outside_set(args.output, args.vtu, args.bc)   # -o must not overwrite the set
        return None if args.max_memory is None else parse_size(args.max_memory)

    max_memory = on_root(comm, check_arguments)
    bed = on_root(comm, read_bed, args.bed, max_memory=max_memory)
    options = dict(accept_unconverged=args.accept_unconverged, max_memory=max_memory,
                   material=given_material(args) or None, material_source="command line",
                   solver=args.solver, **({} if args.box is None else {"box": tuple(args.box)}))
    if args.springs != "paper":   # the voxel model has no springs: refused there by name
        options["springs"] = args.springs
    if args.model != "frame" or args.voxel_size is not None or args.voxel_operator:
        options.update(model=args.model, voxel_size=args.voxel_size,   # voxel model (issue 35)
                       voxel_operator=args.voxel_operator or "assembled")
    if args.bc == "all":
        if "model" in options:
            raise AmfeError("--bc all is not available with --model voxel; give --bc kubc or "
                            "--bc periodic")
        from amfe.cli.bounds import run_all
        return run_all(args, bed, comm, summary, **options)
    result = homogenize(bed, comm=comm, a_star_cap=args.cap_a_star, rtol=args.rtol,
                        vtu_dir=args.vtu, bc=args.bc, diagnose=args.diagnose,
                        progress=not args.quiet, input_path=args.bed, **options)

    def write_and_report():
        # `-o -` (or /dev/stdout): the JSON alone on stdout (for a pipe), the table on stderr
        to_stdout = args.output is not None and is_stdout(args.output)
        table_to = sys.stderr if to_stdout else sys.stdout
        if to_stdout:
            print(json.dumps(result.to_dict(), indent=2), flush=True)
        elif args.output:
            result.to_json(args.output)   # a failed write: one AmfeError naming the path
        print(summary(result.to_dict(), args.bed,
                      None if to_stdout else args.output, args.vtu), file=table_to)
        note = above_e_note(result.properties, result.extra["material"]["E"],
                            result.extra.get("model"))
        if note:
            print(note, file=table_to)
        table_to.flush()

    on_root(comm, write_and_report)
    return 0


def summary(result, bed_path, output=None, vtu=None):
    """A short human-readable table of a homogenization result."""
    s = result["solver"]
    lines = [f"{bed_path}: {result['n_particles']} particles ({result['n_removed']} removed, "
             f"not load-carrying), {result['n_bonds']} bonds, {result['ranks']} rank(s)",
             volume_line(result),
             f"solver: {s['ksp_type']}+{s['pc_type']} rtol {s['rtol']:g}, iterations "
             f"{s['iterations']}, set-up {s['setup_seconds']:.3g} s, "
             f"solves {s['solve_seconds']:.3g} s",
             f"boundary conditions: {result['bc']}; "
             + ", ".join(f"{k.replace('_', ' ')} {v:.1e}" for k, v in s.items()
                         if "asymmetry" in k or k.startswith("love_weber"))]
    if "material" in result:
        m = result["material"]
        lines.append(f"material: E {m['E'] / 1e9:g} GPa, nu {m['nu']:g}, psi {m['psi']:g} "
                     f"({m['source']})")
    springs = result.get("springs") or {}
    if springs.get("name") == "continuum":   # what the fitted springs do not follow (issue 47)
        lines.append(f"springs: continuum (fit {springs.get('version')}): the moduli follow the "
                     "voxel continuum to about a tenth, the Poisson ratios stay too small; for "
                     "them use --model voxel (docs/model.md, section 11)")
    if "model" in result:  # voxel model (issue 35)
        v = result["model"]
        lines.append(f"model: voxel, {'x'.join(map(str, v['voxels']))} voxels of "
                     f"{v['voxel_size']:.4g} m, solid fraction {v['solid_fraction']:.4f}, "
                     f"{v['dofs']} DOFs, {100 * v['necks_resolved_share']:.0f} % of necks "
                     f">= 2 voxels across, {v['pieces_removed']} floating piece(s) removed")
    if "n_capped" in result:
        lines.append(f"a* capped on {result['n_capped']} bonds")
    props = result["properties"]
    for key, unit in PROPERTY_UNITS:
        value = props[key] / 1e9 if unit == "GPa" else props[key]
        lines.append(f"  {key:6s} {value:12.6g} {unit}")
    if "diagnostics" in result:
        lines.append(diagnostics_table(result["diagnostics"]))
    if result.get("warnings"):
        lines.append(f"warnings: {len(result['warnings'])} (printed above; the JSON's "
                     "'warnings' has them in full)")
    if output:
        lines.append(f"wrote {output}")
    if vtu:
        lines.append(f"wrote {os.path.join(vtu, 'cases.pvd')} "
                     "(6 load cases, per unit macro-strain)")
    return "\n".join(lines)


def volume_line(result):
    """V, its box and source, and the solid fraction of that box, as one line."""
    line = f"V = {result['volume']:.4g} m^3"
    box = result.get("volume_box")
    if box:
        line += (f", the {box['source']} " + " x ".join(f"{v * 1e3:.4g}" for v in box["size"])
                 + " mm")
    if "density" in result:
        d = result["density"]
        line += (f"; solid fraction (relative density) {d['solid_fraction']:.4f}, "
                 f"{d['density']:.4g} kg/m^3")
    return line


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

"""`amfe dataset`: a training data set of beds, images and labels, under mpirun, kill-safe.

    mpirun -n N amfe dataset -o DATA.h5 --count M [--seed S] [--scale small|paper]
                             [--ranks-per-bed k] [--max-failed-share F]
    amfe dataset -o DATA.h5 --count M --size X Y Z [--materials steel|draw|316L|Ti64|IN718|AlSi10Mg]
                             [--nu LO HI --psi LO HI]
    amfe dataset --check DATA.h5
    amfe dataset --add-bond-images DATA.h5
    amfe dataset --prefix-of DATA.h5 -o FIRST.h5 [--count N]
    amfe dataset --export-labels DATA.h5 -o LABELS.h5|DIR/ [--count N]
    mpirun -n N amfe dataset --from-labels LABELS.h5 [...] -o DATA.h5 [--count M]

Record k holds the bed with seed record_seed(S, k) of the scale's
distribution (amfe.model.scales), its image (amfe.dataset.images), the six labels and C
(homogenize_bed), the packing density and the generation parameters; it is a
pure function of (S, k), whatever N and k. Rank groups of k ranks take beds
from a shared counter (amfe.dataset.driver). Killing the job loses only the beds in
flight: the same command resumes it (after removing the stale lock
DATA.h5.lock that the kill left; the message says how). The same command
with a larger M grows a finished or unfinished data set, keeping its records. One run at a time
writes an output (amfe.dataset.lock). A bed that fails is recorded as failed
with its reason; more than F of them failed makes the exit status 2. File
layout: amfe.dataset.datafile.
"""
import sys

from amfe.cli.interrupt import launcher_rank
from amfe.cli.options import add_solver_args
from amfe.errors import AmfeError
from amfe.model.conditions import condition_names
from amfe.model.scales import SCALES


def register(sub):
    p = sub.add_parser(
        "dataset", help="make a data set of beds, images and labels (mpirun, resumable)",
        description=__doc__.split("\n\n")[0] + " Run it as `mpirun -n N amfe dataset ...` or "
                    "alone; rerun the same command to resume after a kill.",
        epilog="Any -option (single dash) goes to PETSc. Scales: small (0.6 x 0.6 x 0.3 mm, "
               "images 3x20x20), paper (3 x 3 x 0.3 mm, images 3x100x100); tiny is for tests; "
               "--size X Y Z: small's distribution at any box (docs/datasets.md, Box scales).")
    p.add_argument("-o", "--output", metavar="DATA.h5", help="data-set file to make (HDF5)")
    p.add_argument("--count", type=int, metavar="M",
                   help="number of records; a larger M grows a finished data set or an "
                        "unfinished run, keeping its records and solving only the new ones (the "
                        "other options must be the run's); a smaller one is refused: see "
                        "--prefix-of")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="data-set seed, integer, 0 <= S < 2**64 (default 0)")
    p.add_argument("--scale", default="small", choices=list(SCALES),
                   help="bed distribution (default small; see amfe.model.scales)")
    p.add_argument("--size", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="a box scale instead of --scale: small's scan paths in an X x Y x Z mm "
                        "box (Z a whole number of 0.1 mm layers; amfe.model.boxscale)")
    p.add_argument("--materials", default=None, metavar="M",
                   help="particle material of every bed: steel (default), draw (nu, psi drawn "
                        "per bed), or an alloy: 316L, Ti64, IN718, AlSi10Mg (amfe.model.material)")
    p.add_argument("--nu", nargs=2, type=float, metavar=("LO", "HI"),
                   help="draw nu ~ U(LO, HI) per bed (default with --materials draw: 0.25 0.40)")
    p.add_argument("--psi", nargs=2, type=float, metavar=("LO", "HI"),
                   help="draw psi ~ U(LO, HI) per bed (default with --materials draw: 0.04 0.12)")
    p.add_argument("--ranks-per-bed", type=int, default=1, metavar="K",
                   help="MPI ranks that solve one bed together (default 1)")
    add_solver_args(p)
    p.add_argument("--max-failed-share", type=float, default=None, metavar="F",
                   help="exit with an error (status 2, the file is still written) when more than "
                        "this share of the records failed (default 0.05)")
    p.add_argument("--bc", choices=condition_names(datasets=True), default="kubc",
                   help="boundary conditions of the labels (default kubc; see amfe homogenize "
                        "--bc; data-set beds are not periodic)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--check", metavar="DATA.h5",
                   help="validate a data-set file and print its summary (exit 1 if bad)")
    p.add_argument("--add-bond-images", metavar="DATA.h5",
                   help="add the bond-stiffness images (amfe.dataset.bondimage) to a data set made "
                        "before they existed; regenerates each bed from its seed, no solve")
    p.add_argument("--prefix-of", metavar="DATA.h5",
                   help="write the first --count records (default: all finished in a row) of a "
                        "data set (finished, still being made, or killed) to -o, as that data "
                        "set with --count would be; the run is not disturbed")
    p.add_argument("--export-labels", metavar="DATA.h5",
                   help="write the label table of a data set to -o LABELS.h5 (or, -o an existing "
                        "directory, a new shard of the records its shards lack); see "
                        "docs/datasets.md, Label tables")
    p.add_argument("--from-labels", nargs="+", metavar="LABELS.h5",
                   help="make -o DATA.h5 from label tables (every shard, from the first): beds "
                        "and images regenerated and checked, labels copied, nothing solved; "
                        "the tables give scale, seed and method")
    p.add_argument("--solve-rest", action="store_true",
                   help="with --from-labels: a --count beyond the tables' records solves the "
                        "rest with the tables' method (continues a labelling run from its "
                        "committed tables)")
    p.set_defaults(func=run)


def run(args):
    if args.check:
        if args.output or args.count is not None:
            raise AmfeError("--check FILE validates a file; it takes no -o or --count")
        return _check(args.check)
    if args.add_bond_images:
        if args.output or args.count is not None:
            raise AmfeError("--add-bond-images FILE upgrades a file; it takes no -o or --count")
        return _add_bond_images(args.add_bond_images, not args.no_progress)
    if args.prefix_of:
        return _prefix(args.prefix_of, args.output, args.count)
    if args.export_labels:
        return _export_labels(args.export_labels, args.output, args.count)
    if args.from_labels:
        return _from_labels(args)
    if args.solve_rest:
        raise AmfeError("--solve-rest continues the run of label tables: give --from-labels too")
    if not args.output or args.count is None:
        raise AmfeError("give -o DATA.h5 and --count M (or --check DATA.h5)")
    args.scale = _scale_name(args)
    from amfe.dataset.driver import run_dataset
    from amfe.dataset.plan import DEFAULT_MAX_FAILED_SHARE
    from amfe.model.tolerance import check_command_rtol
    from amfe.solvers.petsc import init_petsc
    check_command_rtol("dataset", args.rtol, "--rtol")   # the loosest rtol (issue 45)
    if init_petsc(args.petsc_args).Options().hasName("ksp_rtol"):   # every rank alike
        raise AmfeError("-ksp_rtol would silently override the tolerance the data set records "
                        "(--rtol, or its default); give the tolerance as --rtol")
    run_dataset(args.output, args.count, seed=args.seed, scale=args.scale,
                ranks_per_bed=args.ranks_per_bed,
                rtol=args.rtol, solver=args.solver, progress=not args.no_progress,
                max_failed_share=DEFAULT_MAX_FAILED_SHARE if args.max_failed_share is None
                else args.max_failed_share, bc=args.bc, springs=args.springs)
    return 0


def _scale_name(args):
    """The scale of the run: --scale's, or the box scale of --size and the material options."""
    from amfe.model.boxscale import box_name
    from amfe.model.scales import MM, get_scale

    if args.size is None and args.materials in (None, "steel") and not (args.nu or args.psi):
        return args.scale
    if args.size is not None and args.scale != "small":
        raise AmfeError("give --size X Y Z or --scale, not both (--size is small's distribution "
                        "at another box)")
    if args.scale == "tiny" and args.size is None:
        raise AmfeError("the tiny scale takes no material options; use --size for a test box")
    size = args.size if args.size is not None else [s / MM for s in get_scale(args.scale).size]
    return box_name(size, args.materials or "steel", args.nu, args.psi)


def _check(path):
    from amfe.dataset.datacheck import check_dataset
    from amfe.dataset.summary import summary_text

    rank = _world_rank()
    if rank != 0:
        return 0
    problems, data, attrs = check_dataset(path)
    if problems:
        print(f"amfe dataset --check: {path} is NOT a valid data set:", file=sys.stderr)
        for p in problems:
            print(f"  - {p}", file=sys.stderr)
        return 1
    print(f"amfe dataset --check: {path} is valid")
    print(summary_text(data, attrs))
    return 0


def _add_bond_images(path, progress):
    from amfe.dataset.upgrade import add_bond_images

    if _world_rank() != 0:
        return 0
    n = add_bond_images(path, progress=progress)
    print(f"amfe dataset: added /bond_images of {n} records to {path}")
    return 0


def _prefix(source, output, count):
    from amfe.dataset.prefix import write_prefix

    if not output:
        raise AmfeError("--prefix-of DATA.h5 needs -o FIRST.h5, the file to write")
    if _world_rank() != 0:
        return 0
    n = write_prefix(source, output, count)
    print(f"amfe dataset: wrote records 0..{n - 1} of {source} to {output}")
    return 0


def _export_labels(source, output, count):
    from amfe.dataset.labels import export_labels

    if not output:
        raise AmfeError("--export-labels DATA.h5 needs -o LABELS.h5 (or a directory of shards)")
    if _world_rank() != 0:
        return 0
    path, first, end = export_labels(source, output, count)
    print(f"amfe dataset: wrote the labels of records {first}..{end - 1} of {source} to {path}")
    return 0


def _from_labels(args):
    from amfe.dataset.driver import run_dataset
    from amfe.dataset.plan import DEFAULT_MAX_FAILED_SHARE

    if not args.output:
        raise AmfeError("--from-labels LABELS.h5 needs -o DATA.h5, the data set to make")
    given = [name for name, value, default in (
        ("--seed", args.seed, 0), ("--scale", args.scale, "small"), ("--rtol", args.rtol, None),
        ("--solver", args.solver, "auto"), ("--bc", args.bc, "kubc"),
        ("--springs", args.springs, "paper"), ("--ranks-per-bed", args.ranks_per_bed, 1),
        ("--size", args.size, None),
        ("--materials", args.materials, None), ("--nu", args.nu, None),
        ("--psi", args.psi, None)) if value != default]
    if given:
        raise AmfeError(f"--from-labels takes the data set's {', '.join(given)} from its tables; "
                        "give none")
    run_dataset(args.output, args.count, from_labels=tuple(args.from_labels),
                solve_rest=args.solve_rest, progress=not args.no_progress,
                max_failed_share=DEFAULT_MAX_FAILED_SHARE if args.max_failed_share is None
                else args.max_failed_share)
    return 0


def _world_rank():
    """This process's rank under mpirun (from the launcher's environment; 0 alone)."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None:
        return mpi.COMM_WORLD.rank
    return launcher_rank()

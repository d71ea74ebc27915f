"""`amfe sweep`: beds over a grid of scan parameters and seeds, solved or predicted, tabulated.

    mpirun -n N amfe sweep -o DIR --grid hatch_spacing=0.1,0.12,0.15 --grid track_width=0.05,0.1
                           [--seeds 4] [--size 0.6 0.6 0.3] [--method solver|surrogate [--fallback]]
                           [--springs paper|continuum]
    amfe sweep -o DIR --file SWEEP.toml

Every bed's row is kept as it finishes: a killed sweep resumes with the same
command. DIR gets beds.csv (a row per bed), points.csv (per point: mean,
standard deviation and count of every constant over the seeds), sweep.h5 (both)
and a plot (sweep_<constant>.png). Lengths take a unit (0.1mm, 100um) or are mm.
"""
import sys

from amfe.cli.interrupt import launcher_rank
from amfe.cli.options import add_flag_share_arg
from amfe.errors import AmfeError
from amfe.io.units import length
from amfe.model.continuum_springs import SPRING_CHOICES


def register(sub):
    p = sub.add_parser(
        "sweep", help="a parameter study: beds over a grid and seeds, solved or predicted",
        description=__doc__.split("\n\n")[0] + " Run it as `mpirun -n N amfe sweep ...` or "
                    "alone; rerun the same command to resume after a kill.",
        epilog="Parameters: track_width, hatch_spacing, angle, layer_rotation, skip_fraction, "
               "skip_length, offset, mean_radius, jitter, layer_thickness, a_star_max, "
               "enlargement_hi, E, nu, psi. Any -option (single dash) goes to PETSc.")
    p.add_argument("-o", "--output", metavar="DIR", required=True,
                   help="directory of the sweep (made if absent; a rerun resumes it)")
    p.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="a parameter and its values (repeat for a grid; lengths in mm or with "
                        "a unit)")
    p.add_argument("--file", metavar="SWEEP.toml",
                   help="the sweep as a TOML file ([grid] or [[point]] tables, seeds, size, "
                        "method, ...; docs/tutorial.md)")
    p.add_argument("--seeds", type=int, default=None, metavar="N",
                   help="bed seeds 0..N-1 at every point (default 4)")
    p.add_argument("--size", nargs=3, type=length("mm"), metavar=("LX", "LY", "LZ"),
                   help="the beds' box, mm when bare (default 0.6 0.6 0.3, the small scale)")
    p.add_argument("--method", choices=["solver", "surrogate"], default=None,
                   help="solver: amfe homogenize each bed (default); surrogate: the shipped "
                        "model's prediction, intervals and flag")
    p.add_argument("--fallback", action="store_true",
                   help="with --method surrogate: solve the beds the surrogate flags")
    p.add_argument("--solver", choices=["auto", "gamg", "cholesky"], default=None,
                   help="how each bed is solved (as amfe homogenize --solver; default auto)")
    p.add_argument("--rtol", type=float, default=None, help="as amfe homogenize --rtol")
    p.add_argument("--ranks-per-bed", type=int, default=None, metavar="K",
                   help="MPI ranks that solve one bed together (default 1)")
    p.add_argument("--springs", choices=SPRING_CHOICES, default=None,
                   help="the bond springs (as amfe homogenize --springs; default paper); with "
                        "--method surrogate, continuum takes the continuum springs' model "
                        "(0.6 mm beds)")
    add_flag_share_arg(p)
    p.add_argument("--plot", default="Ex", metavar="CONSTANT",
                   help="the constant plotted (default Ex; also solid_fraction)")
    p.add_argument("--x", default=None, metavar="NAME", help="the plot's x parameter")
    p.add_argument("--hue", default=None, metavar="NAME",
                   help="one line per value of this parameter (default: the second)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def spec_of(args):
    """The :class:`~amfe.study.spec.SweepSpec` of the command line."""
    from amfe.study.spec import SweepSpec, grid, parse_grid_args, read_spec_file, seeds_of

    if bool(args.grid) == bool(args.file):
        raise AmfeError("amfe sweep: give the grid as --grid NAME=V1,V2,... or as --file "
                        "SWEEP.toml (one of the two)")
    kw = read_spec_file(args.file) if args.file else {"points": grid(parse_grid_args(args.grid))}
    if args.seeds is not None:
        kw["seeds"] = seeds_of(args.seeds)
    kw.setdefault("seeds", seeds_of(4))
    if args.size is not None:
        kw["size"] = tuple(v * 1e-3 for v in args.size)
    for name in ("method", "solver", "rtol", "ranks_per_bed", "springs", "flag_share"):
        if getattr(args, name) is not None:
            kw[name] = getattr(args, name)
    if args.fallback:
        kw["fallback"] = True
    return SweepSpec(**kw)


def run(args):
    from mpi4py import MPI

    from amfe.solvers.petsc import init_petsc
    from amfe.study.plot import plot, preload
    from amfe.study.run import run_sweep
    from amfe.study.table import tables, write_tables

    spec = spec_of(args)
    if spec.method == "solver" or spec.fallback:   # PETSc only when a bed may be solved
        init_petsc(args.petsc_args)
    rows = run_sweep(spec, args.output, comm=MPI.COMM_WORLD,
                     progress=not args.no_progress and launcher_rank() == 0,
                     petsc_args=args.petsc_args,
                     before=preload)
    if MPI.COMM_WORLD.rank != 0:
        return 0
    table = tables(rows, spec.to_dict())
    paths = write_tables(table, args.output)
    import os
    paths.append(plot(table, os.path.join(args.output, f"sweep_{args.plot}.png"), y=args.plot,
                      x=args.x, hue=args.hue))
    print(summary(table, args.plot))
    for path in paths:
        print(f"wrote {path}")
    sys.stdout.flush()
    return 0


def summary(table, y):
    """The points' table as text: each parameter, then y's mean +- std (count)."""
    from amfe.study.plot import _scaled

    names = list(table.spec["points"][0])
    unit = _scaled(y, [0.0])[1]
    lines = ["  ".join(f"{n:>14s}" for n in names) + f"  {y + ' [' + unit + ']':>24s}  n"]
    pts = table.points
    for i in range(len(pts["point"])):
        cells = [f"{_scaled(n, [pts[n][i]])[0][0]:14.4g}" for n in names]
        m = _scaled(y, [pts[f"{y}_mean"][i]])[0][0]
        s = _scaled(y, [pts[f"{y}_std"][i]])[0][0]
        cells.append(f"{m:12.4g} +- {s:<8.3g}  {pts['count'][i]}")
        lines.append("  ".join(cells))
    return "\n".join(lines)

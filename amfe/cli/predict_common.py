"""What every record of ``amfe predict`` shares: the solve of --check and --fallback, the
header and timings, JSON-safe numbers (amfe.cli.predict_core, amfe.cli.predict_any)."""
import math
import time

from amfe.cli.interrupt import launcher_rank
from amfe.errors import AmfeError
from amfe.io.result_meta import header, predict_block
from amfe.model.continuum_springs import SPRING_CHOICES
from amfe.model.material import resolve_material


def solve_for(args, bed, reasons, times, why="the model overflows on this bed",
              springs="paper"):
    """(solver record or None, rank): the bed solved (PETSc, every rank) with --check, or with
    --fallback when flagged. ``reasons`` (the flag's, rank 0's) is made every rank's in place
    (every rank takes the same branch); a non-finite prediction without --fallback is an
    AmfeError (``why`` says which model and constants). springs: the model's labels' bond
    springs (a record, amfe.model.continuum_springs.springs_record), which the solve uses."""
    comm = None
    if args.check or args.fallback:
        from mpi4py import MPI
        comm = MPI.COMM_WORLD
        reasons[:] = comm.bcast(reasons, root=0)
    if "non-finite" in reasons and not args.fallback:
        raise AmfeError(f"the surrogate's prediction is not finite: {why}; run with "
                        "--fallback to solve with PETSc instead, or use amfe homogenize")
    solver = None
    if comm is not None and (args.check or reasons):
        from amfe.solvers.petsc import init_petsc
        init_petsc(args.petsc_args)
        t = time.perf_counter()
        solver = solve_bed(bed, springs)
        times["solve"] = time.perf_counter() - t
    return solver, (comm.rank if comm is not None else launcher_rank())


def solve_bed(bed, springs="paper"):
    """The bed's homogenize JSON (KUBC, GAMG) with ``springs`` (a name or a springs record):
    the solve of --check and --fallback, with the springs of the model's labels."""
    from amfe.model.continuum_springs import springs_of_record
    from amfe.model.options import SolveOptions
    from amfe.solvers.driver import homogenize_bed
    chosen = springs if isinstance(springs, str) else springs_of_record(springs)
    return homogenize_bed(bed, SolveOptions(material=bed.material(), solver="gamg",
                                            springs=chosen)).to_dict()


def check_springs(springs, stiffness):
    """``springs`` as amfe predict and amfe.predict take it: None (the paper's, or the given
    model's own), "paper" or "continuum"; AmfeError for another, and for the continuum
    springs with the full-stiffness model (none is shipped for them)."""
    if springs is not None and springs not in SPRING_CHOICES:
        raise AmfeError(f"predict: springs must be one of {', '.join(SPRING_CHOICES)}, not "
                        f"{springs!r}")
    if stiffness and springs == "continuum":
        raise AmfeError("predict: no shipped full-stiffness model for the continuum springs: "
                        "leave out --stiffness, or solve with amfe homogenize --springs "
                        "continuum (amfe.homogenize(springs='continuum')): its JSON has C and "
                        "the shear moduli")
    return springs


def given_notes(args):
    """The record's note on a material given instead of the bed file's (else none)."""
    given = getattr(args, "material", None)
    if not given:
        return []
    return [f"material from the {getattr(args, 'material_source', 'command line')}: "
            + ", ".join(f"{k} {v:.6g}" for k, v in given.items()) + " (for the bed file's)"]


def flag_share_note(args):
    """The record's note where --flag-share was given but the bed's flag is not a risk's."""
    if getattr(args, "flag_share", None) is None:
        return []
    return [f"flag share {args.flag_share:g} not used: it sets the 0.6 mm model's risk flag, "
            "and this bed is flagged by its interval or the ensemble's spread"]


def finish(out, item, times, t_start):
    """The record with its header, predict block and timings."""
    path, bed = item
    out = {**header("predict", bed.centers, bed.radii, resolve_material(bed.attrs)[1],
                    input_path=path), "springs": {"name": "paper"}, **out,
           "predict": predict_block(out)}
    times["total"] = time.perf_counter() - t_start
    out["seconds"] = times["total"]
    out["timings"] = times
    return out

def finite_or_none(props):
    """{name: value}, a non-finite value as None (JSON null: JSON has no NaN)."""
    return {k: (v if math.isfinite(v) else None) for k, v in props.items()}

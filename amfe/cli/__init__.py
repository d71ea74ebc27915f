"""The `amfe` command: one console script, one module per subcommand in amfe/cli/.

Every subcommand module defines ``register(subparsers)`` which adds its parser
and sets ``func`` to a callable taking the parsed arguments and returning an
exit code. Errors meant for users (:class:`amfe.errors.AmfeError`) are printed
as one line and exit with status 2; nothing else is caught.
"""
import argparse
import importlib
import sys

from amfe.solvers.petsc import is_option

from amfe.errors import AmfeError
from amfe.version import __version__

COMMANDS = ["pack", "homogenize", "dataset", "train", "predict", "view"]


def build_parser():
    parser = argparse.ArgumentParser(
        prog="amfe",
        description="Powder beds as bonded space frames: generate, homogenize, export.")
    parser.add_argument("--version", action="version", version=f"amfe {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"amfe.cli.{name}").register(sub)
    return parser


def split_petsc_args(argv):
    """Split argv into (amfe arguments, PETSc options).

    A PETSc option is a single dash and a name (-ksp_monitor, -pc_type); the
    token after it is its value unless it looks like an option itself. So
    PETSc options go after amfe's own arguments: `amfe homogenize bed.h5
    -ksp_monitor -pc_type hypre`. (Handing them to argparse would read
    -options_left as -o ptions_left.)
    """
    ours, petsc, k = [], [], 0
    while k < len(argv):
        tok = argv[k]
        if _is_petsc_option(tok):
            petsc.append(tok)
            if k + 1 < len(argv) and not is_option(argv[k + 1]):
                petsc.append(argv[k + 1])
                k += 1
        else:
            ours.append(tok)
        k += 1
    return ours, petsc


def _is_petsc_option(tok):
    return len(tok) > 2 and tok[0] == "-" and tok[1] != "-" and tok[1].isalpha()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ours, petsc = split_petsc_args(argv)
    args = build_parser().parse_args(ours)
    args.petsc_args = petsc
    try:
        return int(args.func(args) or 0)
    except AmfeError as exc:
        # Raised alike on every rank: one message, then a clean non-zero exit everywhere.
        if _world_rank() == 0:
            print(f"amfe {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BaseException:
        # An unexpected error on one rank would leave the others waiting in a
        # collective: abort the whole MPI job instead of hanging.
        mpi = sys.modules.get("mpi4py.MPI")
        if mpi is not None and mpi.COMM_WORLD.size > 1:
            import traceback
            traceback.print_exc()
            sys.stderr.flush()
            mpi.COMM_WORLD.Abort(1)
        raise


def _world_rank():
    mpi = sys.modules.get("mpi4py.MPI")
    return mpi.COMM_WORLD.rank if mpi is not None else 0


if __name__ == "__main__":
    sys.exit(main())

"""The `amfe` command: one console script, one module per subcommand in amfe/cli/.

Every subcommand module defines ``register(subparsers)`` which adds its parser
and sets ``func`` to a callable taking the parsed arguments and returning an
exit code. How a run ends:

- an error meant for users (:class:`amfe.errors.AmfeError`) is printed as one
  line, ``amfe <command>: error: ...``, and the exit status is 2; a bad or
  unknown option gets the subcommand's usage and one line (argparse, exit 2);
- SIGINT, SIGTERM, SIGHUP or SIGQUIT, from the first import on: one line,
  ``amfe <command>: interrupted (SIGINT)``, exit 128 + the signal (130, 143,
  129, 131), every MPI rank stopped (amfe.cli.interrupt);
- a reader that closed the pipe (``| head``): quiet, exit 141;
- a full disk: one line naming the file, exit 2;
- anything else is a bug: its traceback, and under MPI an abort of all ranks.
"""
import argparse
import errno
import gc
import importlib
import os
import sys

# One BLAS thread per MPI rank (amfe parallelises over ranks), and the same
# summation order in every run: a Cholesky label must not change in its last
# bit with the machine's core count, or a resumed data set would differ from an
# uninterrupted one. Set before numpy, scipy or PETSc load OpenBLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from amfe.cli.interrupt import (
    Interrupted,
    end_broken_pipe,
    end_interrupted,
    flush_stdout,
    launcher_rank,
    signals_raise,
    world,
)
from amfe.errors import AmfeError
from amfe.io.console import print_warnings
from amfe.solvers.petsc import forget_command_line, init_petsc, is_option
from amfe.version import __version__

COMMANDS = ["pack", "homogenize", "dataset", "train", "predict", "view", "sweep"]
# Commands that hand single-dash options to PETSc (predict: with --check or --fallback).
PETSC_COMMANDS = ("homogenize", "dataset", "predict", "sweep")
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser that speaks on rank 0 only: under `mpirun -n N` every rank parses the
    same command line, and its usage, help or error would otherwise print N times. (The
    subcommands' parsers are of this class too: add_subparsers takes the parent's class.)"""

    def _print_message(self, message, file=None):
        if launcher_rank() == 0:
            super()._print_message(message, file)


def build_parser(only=None):
    """The top-level parser; ``parser.subcommands`` maps each command to its own parser.

    only: one command's name, to register that command alone (a command line that names
    it: the other commands' modules are not imported, 0.1-0.2 s of a rank's start).
    """
    parser = _Parser(
        prog="amfe",
        description="Powder beds as bonded space frames: generate, homogenize, export.")
    parser.add_argument("--version", action="version", version=f"amfe {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in [only] if only in COMMANDS else COMMANDS:
        importlib.import_module(f"amfe.cli.{name}").register(sub)
    parser.subcommands = sub.choices
    return parser


def split_petsc_args(argv):
    """Split argv into (amfe arguments, PETSc options).

    A PETSc option is a single dash and a name (-ksp_monitor, -pc_type); the
    token after it is its value unless it looks like an option itself. So
    PETSc options go after amfe's own arguments: `amfe homogenize bed.h5
    -ksp_monitor -pc_type hypre`. (Handing them to argparse would read
    -options_left as -o ptions_left.) Numbers such as -inf or -1e3 are values.
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
    return (len(tok) > 2 and tok[0] == "-" and tok[1] != "-" and tok[1].isalpha()
            and is_option(tok))


def parse(argv):
    """Parsed arguments (with ``petsc_args``) of the command line ``argv`` (list of str).

    A mistyped option gets the usage of its subcommand, not the top-level one
    (argparse would report the subcommand's leftovers from the top parser);
    PETSc options given to a command that runs no PETSc are refused the same way.
    """
    parser = build_parser(argv[0] if argv else None)
    ours, petsc = split_petsc_args(argv)
    args, extra = parser.parse_known_args(ours)
    sub = parser.subcommands[args.command]
    if extra:
        sub.error(f"unrecognized arguments: {' '.join(extra)}")
    if petsc and args.command not in PETSC_COMMANDS:
        sub.error(f"unrecognized arguments: {' '.join(petsc)} (single-dash options go to "
                  f"PETSc, which amfe {args.command} does not run; its options start with --)")
    args.petsc_args = petsc
    return args


def entry():
    """The console script: :func:`main`, then a quicker end of the process.

    A run that did not start PETSc has its objects frozen out of the garbage collector
    before the interpreter ends (gc.freeze): its last collections over matplotlib's and
    scipy's objects cost 0.1-0.2 s of a sweep or a prediction (measured under mpirun,
    issue 48), and every file amfe writes is closed by then. Objects still go by their
    reference counts, and atexit (MPI's finalisation) runs. A PETSc run ends as before,
    so that its objects are destroyed before PETSc finalises (-log_view's tables).
    """
    code = main()
    if "petsc4py.PETSc" not in sys.modules:
        gc.freeze()
    return code


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    with signals_raise():   # from the start: a Ctrl-C during the imports is one line too
        try:
            args = parse(argv)
        except BrokenPipeError:   # `amfe -h | head -1`
            return end_broken_pipe()
        except SystemExit:
            # -h, --version or a usage error: argparse wrote to stdout, which is block-buffered
            # on a pipe unless PYTHONUNBUFFERED is set; flush it here, where a closed pipe is
            # still ours to catch, not at interpreter exit ("Exception ignored", exit 120).
            if not flush_stdout():
                return end_broken_pipe()
            raise
        except Interrupted as exc:
            return end_interrupted(argv[0] if argv and argv[0] in COMMANDS else "", exc)
        return _run(args)


def _run(args):
    """Run the parsed command; how it ends: see the module's docstring."""
    try:
        if args.petsc_args and "petsc4py.PETSc" not in sys.modules:
            # first: PETSc reads the command line's options (-log_view, -help) when it starts,
            # and the solver layer imports it at module level (amfe.solvers.petsclib)
            init_petsc(args.petsc_args)
        print_warnings()   # the solver layer's warnings, on stderr (amfe.io.console)
        code = int(args.func(args) or 0)
        sys.stdout.flush()   # here, not at exit, so a closed pipe is caught below
        return code
    except AmfeError as exc:
        # Raised alike on every rank: one message, then a clean non-zero exit everywhere.
        if _world_rank() == 0:
            print(f"amfe {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Interrupted as exc:
        return end_interrupted(args.command, exc)
    except BrokenPipeError:
        return end_broken_pipe()
    except OSError as exc:
        if exc.errno not in DISK_FULL:
            _abort_others()
            raise
        # Typically on the writing rank only: stop the others too.
        where = f" writing {exc.filename}" if exc.filename else ""
        print(f"amfe {args.command}: error: no space left on the device{where}; free some "
              "space and run again (files written before are kept)", file=sys.stderr)
        _abort_others(2)
        return 2
    except BaseException:
        _abort_others()
        raise
    finally:
        forget_command_line()   # its PETSc options were this command's (solvers/options.py)


def _abort_others(code=1):
    """An error on one rank would leave the others waiting in a collective: abort the MPI job
    instead of hanging (after printing what went wrong; a no-op without MPI or on one rank)."""
    comm = world()
    if comm is None:
        return
    if code != 2:   # a bug: show where, before the abort ends this process
        import traceback
        traceback.print_exc()
    sys.stderr.flush()
    comm.Abort(code)


def _world_rank():
    mpi = sys.modules.get("mpi4py.MPI")
    return mpi.COMM_WORLD.rank if mpi is not None else launcher_rank()


if __name__ == "__main__":
    sys.exit(main())

"""The `amfe` command: one console script, one module per subcommand in amfe/commands/.

Every subcommand module defines ``register(subparsers)`` which adds its parser
and sets ``func`` to a callable taking the parsed arguments and returning an
exit code. Errors meant for users (:class:`amfe.errors.AmfeError`) are printed
as one line and exit with status 2; nothing else is caught.
"""
import argparse
import importlib
import sys

from .errors import AmfeError

COMMANDS = ["pack", "homogenize"]


def build_parser():
    parser = argparse.ArgumentParser(
        prog="amfe",
        description="Powder beds as bonded space frames: generate, homogenize, export.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"amfe.commands.{name}").register(sub)
    return parser


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    # PETSc options (-ksp_monitor, -log_view, ...) pass through to PETSc untouched.
    args, unknown = parser.parse_known_args(argv)
    petsc_args = [a for a in unknown if a.startswith("-") and not a.startswith("--")]
    stray = [a for a in unknown if a not in petsc_args and not _is_petsc_value(a, unknown)]
    if stray:
        parser.error(f"unrecognised arguments: {' '.join(stray)}")
    args.petsc_args = [a for a in unknown]
    try:
        return int(args.func(args) or 0)
    except AmfeError as exc:
        print(f"amfe {args.command}: error: {exc}", file=sys.stderr)
        return 2


def _is_petsc_value(token, unknown):
    """A token that follows a single-dash PETSc option is its value (-ksp_type cg)."""
    k = unknown.index(token)
    return k > 0 and unknown[k - 1].startswith("-") and not unknown[k - 1].startswith("--")


if __name__ == "__main__":
    sys.exit(main())

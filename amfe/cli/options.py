"""Option value types for the subcommands' parsers: a bad value is refused while parsing.

Also the options several commands share (the material, the memory limit): here, not in
one command's module, so that a command imports only its own (`amfe predict` does not
pull in homogenize's boundary conditions and their scipy modules, 0.2 s of its start).

Each is an argparse ``type``: it returns the converted value or raises
argparse.ArgumentTypeError, which argparse reports as one line under the
subcommand's usage (exit 2) before any work starts. ``float("nan")`` and
``float("inf")`` parse as floats, so every float type here also checks
finiteness: a NaN threshold would otherwise never compare true.
"""
import argparse
import math

from amfe.model.continuum_springs import SPRING_CHOICES

MAX_THREADS = 1024   # more threads than this is a typo (torch would try to start them)


def _number(text, kind):
    """``kind(text)`` (int or float, a float finite), else ArgumentTypeError."""
    try:
        value = kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _checked(kind, low, above=False, high=None):
    """An argparse type: a number of ``kind`` >= low (> low with ``above``), <= high if given."""
    noun = "a whole number" if kind is int else "a finite number"
    words = f"{noun} {'>' if above else '>='} {low:g}"

    def parse(text):
        value = _number(text, kind)
        if value < low or (above and value == low):
            raise argparse.ArgumentTypeError(f"must be {words}, got {text}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"must be at most {high:g}, got {text}")
        return value
    parse.__name__ = f"{kind.__name__} {words}"
    return parse


positive_int = _checked(int, 1)                   # sizes, counts
nonnegative_int = _checked(int, 0)                # worker counts, limits where 0 means none
thread_count = _checked(int, 1, high=MAX_THREADS)
nonnegative_float = _checked(float, 0.0)          # thresholds, weight decay
positive_float = _checked(float, 0.0, above=True)  # learning rates, widths


def open_fraction(text):
    """A number strictly between 0 and 1 (a share)."""
    value = _number(text, float)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text}")
    return value


def add_flag_share_arg(p):
    """--flag-share: the operating point of the 0.6 mm model's risk flag (predict, sweep)."""
    p.add_argument("--flag-share", type=open_fraction, metavar="S",
                   help="the share of its calibration beds that the 0.6 mm model's risk flag "
                        "flags (default 0.19): a larger share flags more beds and leaves fewer "
                        "bad ones unflagged (held out: 0.30 flags about 29-30 %% and leaves "
                        "0.9-1.4 %% of the beds more than 10 %% off and unflagged; "
                        "docs/surrogate.md, \"The flag\"); other beds' flag is their interval's")


def finite_float(text):
    """A finite float (not nan, inf)."""
    return _number(text, float)


def add_solver_args(p):
    """--solver, --rtol and --springs, as homogenize and dataset take them."""
    p.add_argument("--solver", choices=["auto", "gamg", "cholesky"], default="auto",
                   help="auto (default): Cholesky on one rank where its predicted fill is low, "
                        "else CG + GAMG; the constants stay within 1e-5 of a tight reference")
    p.add_argument("--rtol", type=float, default=None,
                   help="GAMG's relative tolerance (default 1e-5 for KUBC on a bed whose hull "
                        "vertices are all prescribed, its stress then second order in the "
                        "error, or whose free hull vertices carry <= 1e-3 of the strain; else "
                        "1e-8 with --solver gamg, 1e-7 when auto picks GAMG)")
    p.add_argument("--springs", choices=SPRING_CHOICES, default="paper",
                   help="the bonds' springs: paper (eqs. 1-4, default) or continuum (calibrated "
                        "on the voxel model of the same spheres, docs/model.md, section 11)")


def add_material_args(p, what):
    """--E, --nu, --psi: the particles' elastic material (shared with `amfe pack`)."""
    p.add_argument("--E", type=float, metavar="PA", help=f"Young's modulus in Pa ({what}; "
                   "default: the bed file's, else steel's 210e9)")
    p.add_argument("--nu", type=float, metavar="NU", help=f"Poisson's ratio ({what}; "
                   "default: the bed file's, else 0.28)")
    p.add_argument("--psi", type=float, metavar="PSI", help=f"psi of paper eqs. 1 and 4 ({what}; "
                   "default: the bed file's, else 0.08)")


def add_memory_arg(p):
    """--max-memory SIZE (shared with `amfe pack`)."""
    p.add_argument("--max-memory", metavar="SIZE", default=None,
                   help="refuse work estimated to need more memory than SIZE (e.g. 8G, 500M), "
                        "in total over the ranks; default: half the machine's memory")


def given_material(args):
    """{"E": ..., "nu": ..., "psi": ...} of the material options given (maybe empty)."""
    return {k: getattr(args, k) for k in ("E", "nu", "psi") if getattr(args, k) is not None}

"""Option value types for the subcommands' parsers: a bad value is refused while parsing.

Each is an argparse ``type``: it returns the converted value or raises
argparse.ArgumentTypeError, which argparse reports as one line under the
subcommand's usage (exit 2) before any work starts. ``float("nan")`` and
``float("inf")`` parse as floats, so every float type here also checks
finiteness: a NaN threshold would otherwise never compare true.
"""
import argparse
import math

MAX_THREADS = 1024   # more threads than this is a typo (torch would try to start them)


def _number(text, kind):
    try:
        return kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") from None


def positive_int(text):
    """An integer >= 1 (thread counts, sizes)."""
    value = _number(text, int)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text}")
    return value


def thread_count(text):
    """A thread count: an integer in [1, MAX_THREADS]."""
    value = positive_int(text)
    if value > MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_THREADS}, got {text}")
    return value


def nonnegative_int(text):
    """An integer >= 0 (worker counts, limits where 0 means none)."""
    value = _number(text, int)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text}")
    return value


def finite_float(text):
    """A finite float (not nan, inf)."""
    value = _number(text, float)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def nonnegative_float(text):
    """A finite float >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def positive_float(text):
    """A finite float > 0."""
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value

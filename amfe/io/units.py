"""Lengths on the command line: a number with a unit (``0.6mm``, ``25um``, ``3e-6m``) or bare.

Every option that takes a length has a default unit, named in its help: a bare
number is read in it, as before, and a number with a unit is converted to it.
So ``--size 600um 600um 0.3mm`` is ``--size 0.6 0.6 0.3`` (mm) and
``--voxel-size 3um`` is ``--voxel-size 3e-6`` (m).
"""
import argparse
import math
import re
from decimal import Decimal

#: Accepted units, as the power of ten of their size in metres ("u" and "µ" both mean micro).
UNITS = {"m": 0, "cm": -2, "mm": -3, "um": -6, "µm": -6, "nm": -9}
_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ]*)\s*$")


def parse_length(text: str, unit: str) -> float:
    """``text`` ("0.6mm", "25 um", "3e-6m" or a bare number in ``unit``) in ``unit``.

    ValueError naming the accepted units for anything else (a finite number is
    required; its sign and range are the option's to check).
    """
    if unit not in UNITS:
        raise ValueError(f"unknown default unit {unit!r}")
    match = _LENGTH.match(str(text))
    if not match or (match.group(2) and match.group(2) not in UNITS):
        raise ValueError(f"{text!r} is not a length: give a number, in {unit} when bare, or with "
                         f"a unit ({', '.join(u for u in UNITS if u != 'µm')}), e.g. 0.6mm or "
                         "25um")
    given = match.group(2) or unit
    # in decimal, so that 100um in mm is the very double that 0.1 is
    value = float(Decimal(match.group(1)).scaleb(UNITS[given] - UNITS[unit]))
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not a finite length")
    return value


def length(unit: str):
    """An argparse ``type`` that reads a length into ``unit`` (see :func:`parse_length`)."""
    def read(text):
        try:
            return parse_length(text, unit)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    read.__name__ = f"length in {unit}"
    return read

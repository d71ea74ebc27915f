"""Lengths with units on the command line (amfe.io.units): values, refusals, and pack's use."""
import argparse

import numpy as np
import pytest
from cli_fixtures import run_main

from amfe.io.bedfile import read_bed
from amfe.io.units import length, parse_length


@pytest.mark.parametrize("text,unit,value", [
    ("0.6", "mm", 0.6), ("0.6mm", "mm", 0.6), ("600um", "mm", 0.6), ("6e-4m", "mm", 0.6),
    ("25um", "um", 25.0), ("0.025 mm", "um", 25.0), ("3e-6m", "m", 3e-6), ("3um", "m", 3e-6),
    ("1cm", "mm", 10.0), ("250nm", "um", 0.25), ("-1mm", "mm", -1.0), (".5", "mm", 0.5)])
def test_a_length_is_read_into_the_options_unit(text, unit, value):
    assert parse_length(text, unit) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize("text", ["0.6 furlong", "mm", "", "0.6mmm", "1e400mm", "nan", "0.6 m m"])
def test_what_is_not_a_length_is_refused_naming_the_units(text):
    with pytest.raises(argparse.ArgumentTypeError, match="length"):
        length("mm")(text)


def test_pack_reads_sizes_with_units_as_bare_millimetres(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    assert run_main(["pack", "-o", a, "--size", "0.1", "0.1", "0.06", "--mean-radius", "12.5",
                     "--seed", "3"])[0] == 0
    assert run_main(["pack", "-o", b, "--size", "100um", "1e-4m", "0.06mm", "--mean-radius",
                     "0.0125mm", "--seed", "3"])[0] == 0
    bed_a, bed_b = read_bed(a), read_bed(b)
    assert np.array_equal(bed_a.centers, bed_b.centers) and np.array_equal(bed_a.radii, bed_b.radii)
    code, out, err = run_main(["pack", "-o", tmp_path / "c.h5", "--size", "0.1", "0.1",
                               "6 furlong"])
    assert code == 2 and "is not a length" in err

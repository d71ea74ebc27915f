"""Command-line faults (issue 31): PETSc options that gave tracebacks or banners, a one-level
GAMG hierarchy, argparse under mpirun, damaged bed files."""
import json

import h5py
import numpy as np
import pytest
from helpers import cubic_lattice, run_cli

from amfe.io.bedfile import write_bed
from amfe.model.bed import Bed, generate_bed


@pytest.fixture(scope="module")
def bed(tmp_path_factory):
    path = tmp_path_factory.mktemp("round2") / "bed.h5"
    write_bed(path, generate_bed(size=(0.2e-3, 0.2e-3, 0.15e-3), seed=1))
    return str(path)


def one_error(proc, command="homogenize"):
    """The single error line of a run that must fail cleanly (exit 2, no traceback, no banner)."""
    assert proc.returncode == 2, proc.stderr
    for junk in ("Traceback", "PETSC ERROR", "MPI_ABORT"):
        assert junk not in proc.stderr, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith(f"amfe {command}: error: ")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.parametrize("opts, match", [
    (["-options_file", "/nonexistent/opts"], "-options_file /nonexistent/opts: the file does "
                                             "not exist"),
    (["-fp_trap"], "-fp_trap is not supported"),
])
def test_petsc_options_that_cannot_start(bed, opts, match):
    """`-options_file /nonexistent` gave PETSc error 83 and a traceback; `-fp_trap` PETSc's
    floating-point banner and MPI_ABORT."""
    assert match in one_error(run_cli(["homogenize", bed, *opts], timeout=120))


def test_gamg_with_one_level_solves_one_case_at_a_time(bed, tmp_path):
    """`--solver gamg -pc_gamg_threshold 0.5` made a one-level hierarchy, and the block path
    raised IndexError. It now solves the six cases one at a time, to the same constants as the
    direct solve."""
    out, ref = tmp_path / "gamg.json", tmp_path / "chol.json"
    p = run_cli(["homogenize", bed, "--solver", "gamg", "-pc_gamg_threshold", "0.5", "--quiet",
                 "-o", str(out)], timeout=120)
    assert p.returncode == 0, p.stderr
    p = run_cli(["homogenize", bed, "--solver", "cholesky", "--quiet", "-o", str(ref)],
                timeout=120)
    assert p.returncode == 0, p.stderr
    got, want = (json.loads(f.read_text())["properties"] for f in (out, ref))
    for key, value in want.items():
        assert got[key] == pytest.approx(value, rel=1e-5), key


@pytest.mark.mpi
@pytest.mark.parametrize("args", [["dataset", "--count", "x"], ["homogenize", "--bogus"],
                                  ["dataset"]])
def test_usage_errors_print_once_under_mpirun(args):
    """Under `mpirun -n 2` every rank parsed the command line and printed its error."""
    p = run_cli(args, ranks=2, timeout=120)
    assert p.returncode == 2
    command = args[0]
    assert sum(ln.startswith(f"amfe {command}: error: ") for ln in p.stderr.splitlines()) == 1
    assert p.stderr.count("usage: ") <= 1, p.stderr


def test_damaged_bed_files_through_the_cli(tmp_path):
    """A bed with 64 flipped bytes (RuntimeError: Unable to get link info) and one whose
    datasets are external links to a missing file (KeyError)."""
    path = tmp_path / "flipped.h5"
    write_bed(path, Bed(*cubic_lattice(3)))
    raw = bytearray(path.read_bytes())
    for k in np.random.default_rng(11).choice(len(raw), 64, replace=False):   # a link-info one
        raw[k] ^= 0xFF
    path.write_bytes(raw)
    linked = tmp_path / "linked.h5"
    with h5py.File(linked, "w") as f:
        f["particles/centers"] = h5py.ExternalLink("gone.h5", "/c")
        f["particles/radii"] = h5py.ExternalLink("gone.h5", "/r")
    for bad in (path, linked):
        line = one_error(run_cli(["homogenize", str(bad)], timeout=120))
        assert f"cannot read bed file {bad}: it is damaged" in line

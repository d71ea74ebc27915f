"""The command line's PETSc options reach PETSc, on 1 and 2 ranks.

solvers/ imports PETSc at module level (amfe.solvers.petsclib); PETSc reads its
command-line options only when it is initialised, so the command line must
initialise it with them before anything imports the solver layer (issue 29).
-log_view and -help act only at PetscInitialize / PetscFinalize: a plain
``from petsc4py import PETSc`` first would lose them silently.
"""
import os

import pytest
from helpers import ROOT, run_cli
from test_golden import write_bed_file

pytestmark = pytest.mark.mpi


@pytest.fixture(scope="module")
def bed(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("argv") / "bed.h5")
    write_bed_file(os.path.join(ROOT, "tests", "data", "golden_bed.json"), path)
    return path


@pytest.mark.parametrize("ranks", [1, 2])
def test_ksp_monitor_and_log_view_reach_petsc(bed, ranks):
    # one case at a time (-amfe_block no): the block path runs its own CG, with no KSP monitor
    proc = run_cli(["homogenize", bed, "--quiet", "--solver", "gamg", "-amfe_block", "no",
                    "-ksp_monitor", "-log_view"], ranks=ranks if ranks > 1 else None)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("KSP Residual norm") >= 6 * 2   # six solves, two lines at least
    assert proc.stdout.count("Performance Summary") == 1     # rank 0 prints -log_view's report
    assert f"with {ranks} processor" in proc.stdout            # -log_view saw every rank
    assert "never used" not in proc.stderr


@pytest.mark.parametrize("ranks", [1, 2])
def test_help_reaches_petsc(bed, ranks):
    proc = run_cli(["homogenize", bed, "--quiet", "-help"], ranks=ranks if ranks > 1 else None)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout + proc.stderr
    assert "Options for all PETSc programs" in out
    assert "-ksp_type <" in out and "-pc_type <" in out   # the solve's own options, documented

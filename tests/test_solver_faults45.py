"""Issue 45, items 5, 8, 10 (the solver's wordings) and 11 (-ksp_norm_type none): --diagnose
describes the run's own preconditioner, options that crash PETSc 3.18 are refused as a class,
-ksp_monitor prints in the default solve, and the progress lines name what runs."""
import logging

import pytest
from cli_fixtures import assert_one_error, run_main
from helpers import run_cli

from amfe.errors import AmfeError
from amfe.model.options import SolveOptions
from amfe.solvers.driver import homogenize_bed


@pytest.mark.parametrize("bc", ["kubc", "subc"])
def test_diagnose_solves_with_the_runs_preconditioner(bed, bc):
    """Item 5: the diagnosis ran smoothed aggregation while the run (and the JSON) was
    unsmoothed: other iterations (4 4 4 4 5 4 against 4 5 5 5 5 5 on this bed). Now the same
    iterations per case, and true residuals within 1e-3 of each other (the block CG and
    KSPCG sum in another order)."""
    plain = homogenize_bed(bed, SolveOptions(solver="gamg", bc=bc)).solver
    diag = homogenize_bed(bed, SolveOptions(solver="gamg", bc=bc, diagnose=True)).solver
    assert diag["iterations"] == plain["iterations"]
    assert diag.get("multigrid") == plain.get("multigrid")
    for a, b in zip(plain["residuals"], diag["residuals"]):
        assert abs(a - b) <= 1e-3 * a


CRASHING = [["-mg_levels_ksp_type", "preonly"], ["-mg_levels_1_ksp_type", "preonly"],
            ["-mg_levels_ksp_type", "PREONLY", "-mg_levels_pc_type", "none"],
            ["-pc_gamg_type", "geo"]]


@pytest.mark.parametrize("argv", CRASHING + [["--model", "voxel", *a] for a in CRASHING[:1]])
def test_options_that_crash_petsc_are_refused_first(bed_path, argv, tmp_path):
    """Item 8: SEGV with a PETSc dump (exit 59), or a PETSc stack before amfe's line. In a
    subprocess: without the refusal the crash would take the test session with it."""
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", bed_path, "-o", str(out), "--quiet", *argv], timeout=120)
    line = assert_one_error(proc.returncode, proc.stderr, "homogenize")
    assert "PETSC ERROR" not in proc.stderr and "not supported" in line or "geo needs" in line
    assert not out.exists()


def test_the_refusal_reaches_per_solve_options_too(bed):
    # (in this process: -mg_levels_ksp_type preonly would crash it where not refused)
    for opts in ({"pc_gamg_type": "geo"}, {"-pc_gamg_type": "GEO"}):
        with pytest.raises(AmfeError, match="geo needs"):
            homogenize_bed(bed, SolveOptions(solver="gamg", ksp_options=opts))


def test_voxel_preonly_is_one_line_not_a_traceback(bed_path, tmp_path):
    """Item 8: --model voxel -ksp_type preonly: preonly refused the affine initial guess
    (a Python traceback); now the inexact solve meets the contract's check."""
    proc = run_cli(["homogenize", bed_path, "--model", "voxel", "--voxel-size", "5e-6", "-o",
                    str(tmp_path / "r.json"), "--quiet", "-ksp_type", "preonly"], timeout=120)
    line = assert_one_error(proc.returncode, proc.stderr, "homogenize")
    assert "PREONLY solve with gamg stopped" in line


def test_norm_type_none_is_refused_before_the_solve(bed_path, tmp_path):
    """Item 11: -ksp_norm_type none ran CG to its 10 000 iterations (43 s on the issue's bed)
    before the contract refused it."""
    code, _, err = run_main(["homogenize", bed_path, "-o", str(tmp_path / "r.json"), "--quiet",
                             "--solver", "gamg", "-ksp_norm_type", "none"])
    line = assert_one_error(code, err, "homogenize")
    assert "-ksp_norm_type none" in line and "cannot test convergence" in line


def test_ksp_monitor_prints_in_the_default_solve(bed_path, tmp_path):
    """Item 10: -ksp_monitor printed nothing in the block solve, and said nothing."""
    proc = run_cli(["homogenize", bed_path, "--solver", "gamg", "-o", str(tmp_path / "r.json"),
                    "-ksp_monitor"], timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [s for s in proc.stdout.splitlines() if "KSP Residual norm" in s]
    assert sum(s.split()[0] == "0" for s in lines) == 6   # one history per load case
    assert "solved one at a time" in proc.stderr + proc.stdout


def test_progress_names_the_preconditioner_given(bed, caplog):
    """Item 10: -pc_type hypre printed "solver: gamg" before the summary said cg+hypre."""
    with caplog.at_level(logging.INFO, logger="amfe.solvers"):
        r = homogenize_bed(bed, SolveOptions(solver="gamg", ksp_options={"pc_type": "hypre"}))
    assert r.solver["pc_type"] == "hypre"
    line, = [m for m in caplog.messages if m.startswith("solver:")]
    assert "cg + hypre" in line and "solver: gamg" not in line


def test_cholesky_on_two_ranks_names_no_option_homogenize_lacks():
    from amfe.solvers.choice import choose_solver
    with pytest.raises(AmfeError) as err:
        choose_solver({"n_particles": 10}, 2, "cholesky")
    assert "one rank" in str(err.value) and "amfe dataset: --ranks-per-bed 1" in str(err.value)

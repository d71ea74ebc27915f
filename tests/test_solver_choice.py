"""--solver auto|gamg|cholesky: the rule, the label contract, and what the records say."""
import json

import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays, run_cli

from amfe.errors import AmfeError
from amfe.model.frame import build_frame
from amfe.model.scales import bed_for
from amfe.solvers.choice import (
    FILL_RATIO_MAX,
    GAMG_RTOL_AUTO,
    MAX_DIRECT_PARTICLES,
    Problem,
    choose_solver,
    solve_features,
)
from amfe.solvers.correction import CORRECTED_RTOL
from amfe.vocab import CONSTANT_NAMES

SPARSE = {"n_particles": 3000, "n_bonds": 9000, "fill_ratio": FILL_RATIO_MAX - 1}
DENSE = {"n_particles": 9000, "n_bonds": 40000, "fill_ratio": FILL_RATIO_MAX + 1}


def test_the_rule_picks_each_method_where_it_should():
    assert choose_solver(SPARSE, 1)[0] == "cholesky"
    assert choose_solver(DENSE, 1)[:3:2] == ("gamg", GAMG_RTOL_AUTO)
    assert choose_solver(SPARSE, 2)[0] == "gamg"                      # several ranks
    huge = dict(SPARSE, n_particles=MAX_DIRECT_PARTICLES + 1)
    assert choose_solver(huge, 1)[0] == "gamg"
    assert choose_solver(SPARSE, 1, package=None)[0] == "gamg"         # no factorisation package
    assert choose_solver(SPARSE, 1, user_options=["pc_type"])[0] == "gamg"  # the user's choice
    # free rigid modes
    assert choose_solver(SPARSE, 1, problem=Problem(singular=True))[0] == "gamg"
    assert choose_solver(SPARSE, 1, rtol=1e-9)[0] == "cholesky"
    assert choose_solver(DENSE, 1, rtol=1e-9)[2] == 1e-9
    # a second-order answer (KUBC on a box) takes the corrected default, auto and gamg alike
    assert choose_solver(DENSE, 1, problem=Problem(corrected=True))[2] == CORRECTED_RTOL
    assert choose_solver(DENSE, 1, "gamg", problem=Problem(corrected=True))[2] == CORRECTED_RTOL
    assert choose_solver(DENSE, 1, "gamg")[2] == 1e-8
    assert choose_solver(DENSE, 1, rtol=1e-9, problem=Problem(corrected=True))[2] == 1e-9
    assert choose_solver(DENSE, 1, "cholesky")[0] == "cholesky"
    assert choose_solver(SPARSE, 1, "gamg")[2] == 1e-8
    for bad in (dict(requested="cholesky", nranks=2), dict(requested="cholesky", nranks=1,
                                                           problem=Problem(singular=True)),
                dict(requested="lu", nranks=1)):
        with pytest.raises(AmfeError):
            choose_solver(SPARSE, **bad)


def test_features_do_not_need_a_solve_and_only_run_when_asked():
    calls = []
    choose_solver(lambda: calls.append(1) or SPARSE, 2)
    assert calls == []   # two ranks: no features computed
    x, r = cubic_lattice(6)
    f = solve_features(build_frame(x, r))
    assert f["n_particles"] == 216 and f["n_bonds"] == 3 * 36 * 5
    # The envelope holds at least every bond (fill >= 1); RCM's level sets on the
    # lattice are the diagonal planes x+y+z = c (at most 27 of the 216 particles), so
    # no row reaches back further than two of them: fill <= (54 * 216 + 216) / 756.
    assert 1.0 <= f["fill_ratio"] <= (54 * 216 + 216) / 756
    # and the envelope is a real bound on the factor: far below the dense 216 / 2 per row
    assert f["fill_ratio"] < 216 / 2 * 216 / 756


@pytest.mark.parametrize("seed", [3, 11])
def test_every_method_meets_the_contract_on_small_beds(seed):
    bed = bed_for("tiny", seed)
    ref = homogenize_arrays(bed.centers, bed.radii, rtol=1e-10, solver="gamg")
    for solver in ("auto", "gamg", "cholesky"):
        res = homogenize_arrays(bed.centers, bed.radii, solver=solver)
        assert res["solver"]["method"] in ("gamg", "cholesky") and res["solver"]["reason"]
        for k in CONSTANT_NAMES:
            assert res["properties"][k] == pytest.approx(ref["properties"][k], rel=1e-5)
    chol = homogenize_arrays(bed.centers, bed.radii, solver="cholesky")
    np.testing.assert_allclose(chol["C"], ref["C"], rtol=1e-8, atol=1e-8 * np.abs(ref["C"]).max())


def test_a_sparse_bed_is_factorised_and_the_json_says_why(tmp_path):
    bed_path = tmp_path / "bed.h5"
    proc = run_cli(["pack", "-o", str(bed_path), "--scale", "small", "--seed", "1428955016"])
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(bed_path), "-o", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    s = json.loads(out.read_text())["solver"]
    assert s["method"] == "cholesky" and "predicted fill" in s["reason"]
    assert s["requested"] == "auto"


def test_two_ranks_use_gamg_and_cholesky_is_refused_there(tmp_path):
    bed_path = tmp_path / "bed.h5"
    assert run_cli(["pack", "-o", str(bed_path), "--size", "0.1", "0.1", "0.06"]).returncode == 0
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(bed_path), "-o", str(out), "--quiet"], ranks=2)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(out.read_text())["solver"]
    assert s["method"] == "gamg" and "2 ranks" in s["reason"] and s["rtol"] == CORRECTED_RTOL
    proc = run_cli(["homogenize", str(bed_path), "--solver", "cholesky", "--quiet"], ranks=2)
    assert proc.returncode == 2 and "one rank" in proc.stderr


def test_the_data_set_records_which_method_labelled_each_bed(tmp_path):
    import h5py
    out = tmp_path / "d.h5"
    proc = run_cli(["dataset", "-o", str(out), "--count", "6", "--scale", "tiny",
                    "--seed", "5", "--no-progress", "--max-failed-share", "1"])
    assert proc.returncode == 0, proc.stderr
    with h5py.File(out) as f:
        records = [json.loads(s) for s in f["solver"].asstr()[()] if s]
        assert f.attrs["solver"] == "auto"
    assert len(records) >= 5
    assert {r["method"] for r in records} <= {"gamg", "cholesky"}
    assert all(r["reason"].startswith("auto:") for r in records)


def test_given_options_reads_both_spellings_and_the_database():
    # the solver choice and the multigrid choice ask the same question: did the caller set it?
    from amfe.solvers.inputs import given_options
    from amfe.solvers.petsclib import PETSc
    names = ("pc_type", "ksp_type", "pc_gamg_agg_nsmooths")
    assert given_options(names, {"-pc_type": "lu", "ksp_type": "preonly"}) == ["pc_type",
                                                                               "ksp_type"]
    db = PETSc.Options()
    db.setValue("pc_gamg_agg_nsmooths", "1")
    try:
        assert given_options(names, None) == ["pc_gamg_agg_nsmooths"]
    finally:
        db.delValue("pc_gamg_agg_nsmooths")
    assert given_options(names, {}) == []

"""The speed-against-error report (run/report.py) on a tiny case: invariants of its numbers."""
import json
import os
import subprocess
import sys

import pytest

from helpers import MPI_ENV, ROOT

sys.path.insert(0, os.path.join(ROOT, "run"))
import report_measure as M  # noqa: E402


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    p = subprocess.run([sys.executable, os.path.join(ROOT, "run", "report.py"), "--tiny",
                        "--sections", "1,2,3,5", "--out", str(out)], cwd=ROOT, env=MPI_ENV,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    with open(out / "report.json") as fh:
        return out, json.load(fh)


def test_files_written(report):
    out, data = report
    for name in ("report.md", "report_pareto.png", "report_scaling.png", "report_rve.png"):
        assert (out / name).stat().st_size > 1000, name
    md = (out / "report.md").read_text()
    assert data["machine"]["petsc"] in md and data["machine"]["date"] in md
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


def test_accuracy_falls_with_rtol(report):
    acc = report[1]["accuracy"]
    for method in ("CG + GAMG", "CG + Jacobi"):
        rs = sorted((r for r in acc["runs"] if r["method"] == method), key=lambda r: -r["rtol"])
        errs = [r["error"] for r in rs]
        # an rtol 1e4 times smaller gives constants at least 10x closer to the reference
        assert all(b < a / 10 for a, b in zip(errs, errs[1:])), (method, errs)
        assert errs[-1] < 1e-7
    direct = [r for r in acc["runs"] if r["rtol"] is None]
    assert {"Cholesky (MUMPS)", "scipy SuperLU"} <= {r["method"] for r in direct}
    assert all(r["error"] < 1e-9 for r in direct)        # independent solvers agree
    rec = acc["recommended"]
    assert rec["error"] <= 1e-6
    assert all(rec["seconds"] <= r["seconds"] for r in acc["runs"] if r["error"] <= 1e-6)


def test_scaling_rank_invariant_and_phases(report):
    data = report[1]
    rows = data["scaling"]
    assert {r["ranks"] for r in rows} == {1, 2}
    assert data["rank_invariance"] < 1e-6
    for r in rows:
        phases = sum(r[p] for p in ("generate", "bonds", "assemble", "setup", "solves",
                                    "averages"))
        assert phases <= r["total"] * 1.001 and phases > 0.5 * r["total"]
        assert 3 <= r["iterations"] <= 15 and r["matvecs_per_solve"] > r["iterations"]


def test_rve_summary_logic():
    rows = [{"side_mm": b, "n_particles": 100 * b, "total": b, "properties":
             dict.fromkeys(M.CONSTANTS, v)} for b, v in ((1, 1.3), (2, 1.005), (3, 1.0))]
    table, rve = M.rve_summary(rows)
    assert [round(t["change"], 3) for t in table] == [0.3, 0.005, 0.0]
    assert rve == 2


def test_pareto_front_and_fit():
    runs = [{"seconds": 1, "error": 1e-2}, {"seconds": 2, "error": 1e-3},
            {"seconds": 3, "error": 1e-2}, {"seconds": 4, "error": 1e-6}]
    assert [r["seconds"] for r in M.pareto_front(runs)] == [1, 2, 4]
    assert M.fit_exponent([1e3, 1e4, 1e5], [2.0, 20.0, 200.0]) == pytest.approx(1.0)


def test_rve_extrapolation_recovers_boundary_layer():
    table = [{"side_mm": b, "mean": {k: 2.0 + 0.1 / b for k in M.CONSTANTS}}
             for b in (1.0, 2.0, 3.0, 4.0)]
    ex = M.rve_extrapolate(table)
    assert ex["c_inf"]["Ex"] == pytest.approx(2.0) and ex["a"]["G_xy"] == pytest.approx(0.1)
    assert ex["side_at_tol"] == pytest.approx(5.0) and ex["worst_residual"] < 1e-12
    assert M.rve_extrapolate(table[:2]) is None


@pytest.mark.parametrize("args", [["--sections", "1,9"], ["--out", os.devnull]])
def test_bad_arguments_exit_2(args):
    p = subprocess.run([sys.executable, os.path.join(ROOT, "run", "report.py"), *args],
                       cwd=ROOT, env=MPI_ENV, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "report.py:" in p.stderr and "Traceback" not in p.stderr

"""amfe sweep: a grid of scan parameters times seeds, its tables, its resumption and its rows."""
import csv
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from cli_fixtures import run_main
from helpers import MPI_ENV, ROOT, run_cli

import amfe
from amfe.errors import AmfeError
from amfe.study.spec import SweepSpec, read_spec_file

GRID = ["--grid", "hatch_spacing=0.1,0.12", "--grid", "track_width=0.05,0.08"]
TINY = ["--size", "0.2", "0.2", "0.2", "--seeds", "2", "--no-progress"]
CONSTANTS = ["Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy"]


def read_csv(path, drop=("seconds [s]",)):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return [{k: v for k, v in r.items() if k not in drop} for r in rows]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "s"
    code, stdout, err = run_main(["sweep", "-o", out, *GRID, *TINY])
    assert code == 0, err
    return out, stdout


def test_it_writes_every_table_and_the_plot(swept):
    out, stdout = swept
    for name in ("beds.csv", "points.csv", "sweep.h5", "sweep_Ex.png", "sweep.json"):
        assert (out / name).is_file(), name
    beds = read_csv(out / "beds.csv")
    assert len(beds) == 8 and {r["source"] for r in beds} == {"solver"}
    assert "Ex [GPa]" in stdout


def test_the_points_are_the_mean_and_spread_of_their_beds(swept):
    out, _ = swept
    beds, points = read_csv(out / "beds.csv"), read_csv(out / "points.csv")
    for p in points:
        mine = [float(b["Ex [Pa]"]) for b in beds if b["point"] == p["point"]]
        assert int(p["count"]) == len(mine) == 2
        assert float(p["Ex_mean [Pa]"]) == pytest.approx(np.mean(mine), rel=1e-15)
        assert float(p["Ex_std [Pa]"]) == pytest.approx(np.std(mine, ddof=1), rel=1e-12)
    import h5py
    with h5py.File(out / "sweep.h5") as f:
        assert np.array_equal(f["beds/Ex"][()], [float(b["Ex [Pa]"]) for b in beds])
        assert json.loads(f.attrs["spec"])["seeds"] == [0, 1]


def test_a_row_equals_amfe_homogenize_of_the_same_bed(swept, tmp_path):
    out, _ = swept
    row = read_csv(out / "beds.csv")[5]           # point 2 (0.12, 0.05 mm), seed 1
    assert (row["point"], row["seed"]) == ("2", "1")
    bed = tmp_path / "bed.h5"
    pack = run_cli(["pack", "-o", str(bed), "--size", "0.2", "0.2", "0.2", "--track-width",
                    "0.05", "--hatch-spacing", "0.12", "--seed", "1", "--skip-seed", "1"])
    assert pack.returncode == 0, pack.stderr
    solve = run_cli(["homogenize", str(bed), "-o", str(tmp_path / "r.json"), "--quiet"])
    assert solve.returncode == 0, solve.stderr
    with open(tmp_path / "r.json") as f:
        props = json.load(f)["properties"]
    for name in CONSTANTS:
        unit = "Pa" if name[0] in "EG" else "-"
        assert float(row[f"{name} [{unit}]"]) == pytest.approx(props[name], rel=1e-12, abs=0)


def test_the_python_face_gives_the_command_lines_table(swept, tmp_path):
    out, _ = swept
    table = amfe.sweep({"hatch_spacing": [0.1e-3, 0.12e-3], "track_width": [0.05e-3, 0.08e-3]},
                       seeds=2, size=(0.2e-3, 0.2e-3, 0.2e-3), output=tmp_path / "py")
    cli = read_csv(out / "beds.csv")
    assert table.beds["Ex"].tolist() == [float(r["Ex [Pa]"]) for r in cli]
    assert "4 points" in repr(table)


def test_a_killed_sweep_resumes_to_the_same_table(swept, tmp_path):
    out, _ = swept
    again = tmp_path / "k"
    cmd = [sys.executable, "-m", "amfe.cli", "sweep", "-o", str(again), *GRID, *TINY]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=MPI_ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    rows = again / "rows"
    while time.monotonic() < deadline and (not rows.is_dir() or len(os.listdir(rows)) < 3):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 3 <= len(os.listdir(rows)) < 8 or not (again / "beds.csv").exists()
    code, _, err = run_main(["sweep", "-o", again, *GRID, *TINY])
    assert code == 0, err
    for name in ("beds.csv", "points.csv"):
        assert read_csv(again / name) == read_csv(out / name), name


def test_another_sweep_in_the_same_directory_is_refused(swept):
    out, _ = swept
    code, _, err = run_main(["sweep", "-o", out, "--grid", "hatch_spacing=0.1", *TINY])
    assert code != 0 and "holds another sweep" in err


def test_a_toml_file_gives_the_same_spec(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('seeds = 2\nsize = ["0.2mm", "200um", 0.2]\n[grid]\n'
                 'hatch_spacing = [0.1, "0.12mm"]\ntrack_width = ["50um", 0.08]\n')
    spec = SweepSpec(**read_spec_file(f))
    assert spec.points[1] == {"hatch_spacing": 0.1e-3, "track_width": 0.08e-3}
    assert spec.size == (0.2e-3, 0.2e-3, 0.2e-3) and spec.n_beds == 8


@pytest.mark.parametrize("args,match", [
    (["--grid", "hatch=0.1"], "unknown parameter"),
    (["--grid", "hatch_spacing=0.1,abc"], "is not a length"),
    (["--grid", "hatch_spacing"], "NAME=V1"),
    (["--grid", "hatch_spacing=0.1", "--fallback"], "needs --method surrogate")])
def test_bad_sweeps_are_one_line(tmp_path, args, match):
    code, _, err = run_main(["sweep", "-o", tmp_path / "x", *args, *TINY])
    assert code != 0 and match in err and "Traceback" not in err


def test_a_bed_that_cannot_be_made_is_a_failed_row(tmp_path):
    table = amfe.sweep({"track_width": [0.05e-3]}, seeds=1, size=(0.2e-3, 0.2e-3, 0.2e-3),
                       base={"hatch_spacing": 0.05e-3, "mean_radius": 1.0})
    assert table.beds["source"].tolist() == ["failed"] and "error" in table.beds
    with pytest.raises(AmfeError, match="unknown parameter"):
        amfe.sweep({"hatch": [1e-4]}, seeds=1)


def test_the_surrogate_rows_and_the_fallback(tmp_path):
    """On the shipped model's size: every row has intervals and a flag; with --fallback a
    flagged row is solved (source solver, the solver's constants), the others keep the
    surrogate's."""
    grid = ["--grid", "hatch_spacing=0.1", "--grid", "track_width=0.05,0.1", "--seeds", "2",
            "--no-progress", "--method", "surrogate"]
    code, _, err = run_main(["sweep", "-o", tmp_path / "s", *grid])
    assert code == 0, err
    code, _, err = run_main(["sweep", "-o", tmp_path / "f", *grid, "--fallback"])
    assert code == 0, err
    alone, fall = read_csv(tmp_path / "s" / "beds.csv"), read_csv(tmp_path / "f" / "beds.csv")
    assert {r["source"] for r in alone} == {"surrogate"}
    assert all(r["Ex_lo [Pa]"] and float(r["Ex_lo [Pa]"]) <= float(r["Ex [Pa]"]) for r in alone)
    for a, f in zip(alone, fall):
        assert f["flagged"] == a["flagged"]
        assert f["source"] == ("solver" if a["flagged"] == "true" else "surrogate")
        if f["source"] == "surrogate":
            assert f["Ex [Pa]"] == a["Ex [Pa]"]
    points = read_csv(tmp_path / "f" / "points.csv")
    assert sum(int(p["solved"]) for p in points) == sum(r["source"] == "solver" for r in fall)
    # a surrogate row's solid fraction is its image's mean: within the stated 1e-3 of the
    # one a solver sweep computes for the same beds (amfe.dataset.density)
    solver_grid = [g for g in grid if g not in ("--method", "surrogate")]
    code, _, err = run_main(["sweep", "-o", tmp_path / "v", *solver_grid])
    assert code == 0, err
    for a, v in zip(alone, read_csv(tmp_path / "v" / "beds.csv")):
        assert a["seed"] == v["seed"]
        assert abs(float(a["solid_fraction [-]"]) - float(v["solid_fraction [-]"])) <= 1e-3


def test_every_method_writes_the_same_layout(tmp_path):
    """A solver sweep's beds table and a surrogate sweep's have the same columns in the same
    order (issue 48): a solver row's intervals and flag are empty cells, a surrogate row's
    shear moduli too; the values themselves land in their columns."""
    from amfe.study.table import tables, write_tables

    spec = {"points": [{"hatch_spacing": 1e-4}]}
    base = {"index": 0, "point": 0, "seed": 0, "hatch_spacing": 1e-4, "n_particles": 10,
            "solid_fraction": 0.5, "seconds": 1.0}
    consts = {n: 1e9 * (k + 1) for k, n in enumerate(CONSTANTS)}
    solver = {**base, **consts, "n_removed": 0, "warnings": "", "source": "solver"}
    surrogate = {**base, **{n: consts[n] for n in CONSTANTS[:6]}, "Ex_lo": 0.9e9,
                 "Ex_hi": 1.1e9, "source": "surrogate", "flagged": True,
                 "flag_reasons": "fill"}
    heads = []
    for name, row in (("v", solver), ("s", surrogate)):
        (tmp_path / name).mkdir()
        write_tables(tables([row], spec), tmp_path / name)
        with open(tmp_path / name / "beds.csv") as f:
            heads.append(f.readline())
    assert heads[0] == heads[1]
    assert "G_yz [Pa]" in heads[0] and "Ex_lo [Pa]" in heads[0] and "flagged" in heads[0]
    v, s = read_csv(tmp_path / "v" / "beds.csv")[0], read_csv(tmp_path / "s" / "beds.csv")[0]
    assert (v["Ex_lo [Pa]"], v["flagged"], s["G_yz [Pa]"]) == ("", "", "")
    assert float(s["Ex_lo [Pa]"]) == 0.9e9 and s["flagged"] == "true"
    assert float(v["G_xy [Pa]"]) == consts["G_xy"]


def test_a_sweep_with_the_continuum_springs(tmp_path):
    """--springs continuum: the solver rows are amfe.homogenize(springs="continuum") of the
    same beds, the surrogate rows the continuum springs' model's, and the spec records the
    springs (a paper sweep's spec does not name them: its fingerprint is as before)."""
    from amfe.study.run import bed_of
    grid = ["--grid", "hatch_spacing=0.1", "--grid", "track_width=0.05", "--seeds", "2",
            "--no-progress", "--springs", "continuum"]
    code, _, err = run_main(["sweep", "-o", tmp_path / "v", *grid])
    assert code == 0, err
    spec = SweepSpec(points=({"hatch_spacing": 1e-4, "track_width": 5e-5},), seeds=(0, 1),
                     springs="continuum")
    assert json.loads((tmp_path / "v" / "sweep.json").read_text())["springs"] == "continuum"
    assert "springs" not in SweepSpec(points=spec.points, seeds=(0,)).to_dict()
    solved = read_csv(tmp_path / "v" / "beds.csv")
    for k, row in enumerate(solved):
        want = amfe.homogenize(bed_of(spec, k)[0], springs="continuum")
        assert float(row["Ex [Pa]"]) == pytest.approx(want.Ex, rel=1e-12)
        assert float(row["Ex [Pa]"]) != pytest.approx(amfe.homogenize(bed_of(spec, k)[0]).Ex,
                                                      rel=1e-3)
    code, _, err = run_main(["sweep", "-o", tmp_path / "s", *grid, "--method", "surrogate"])
    assert code == 0, err
    for row, truth in zip(read_csv(tmp_path / "s" / "beds.csv"), solved):
        assert row["source"] == "surrogate"
        assert abs(float(row["Ex [Pa]"]) / float(truth["Ex [Pa]"]) - 1) < 0.15
    with pytest.raises(AmfeError, match="springs must be one of"):
        SweepSpec(points=spec.points, seeds=(0,), springs="voxel")


def test_ranks_claim_every_bed_once_and_give_the_one_rank_table(swept, tmp_path):
    """Three ranks (on two cores) claim the chunks as they finish them: every bed is done
    once, the table is the one-rank sweep's, and no claim is left behind."""
    out, _ = swept
    many = tmp_path / "m"
    shown = [a for a in TINY if a != "--no-progress"]   # the bar counts every rank's beds
    proc = run_cli(["sweep", "-o", str(many), *GRID, *shown], ranks=3)
    assert proc.returncode == 0, proc.stderr
    assert "8/8" in proc.stderr.replace("\r", "\n").strip().splitlines()[-1]
    assert read_csv(many / "beds.csv") == read_csv(out / "beds.csv")
    assert sorted(os.listdir(many / "rows")) == [f"row_{k:06d}.json" for k in range(8)]
    assert not (many / ".claims").exists()


@pytest.mark.parametrize("n, groups, step", [(36, 2, 16), (8, 3, 1), (1, 4, 16), (0, 2, 16),
                                             (100, 1, 16), (37, 5, 4)])
def test_the_chunks_cover_the_beds_once_in_order(n, groups, step):
    from amfe.study.run import _chunks

    todo = list(range(3, 3 + n))
    chunks = _chunks(todo, groups, step)
    assert [k for c in chunks for k in c] == todo
    sizes = [len(c) for c in chunks]
    assert all(1 <= s <= step for s in sizes)
    assert sizes == sorted(sizes, reverse=True)   # guided: the last chunks are the small ones

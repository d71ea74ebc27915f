"""Label tables (issue 32): export, rebuild without solving, refusals, re-solve contract.

A `tiny` data set (a fifth of its beds fail on purpose) is made once by
`amfe dataset`; its table is exported and the data set rebuilt from it by
`amfe dataset --from-labels` under mpirun. The rebuild must equal the original
bit for bit in every field a rebuild stores or recomputes.
"""
import json
import shutil

import h5py
import numpy as np
import pytest
from helpers import run_cli

from amfe.dataset.labels import IDENTITY, MAX_TABLE_BYTES, bed_digest, kept_solver
from amfe.dataset.parts import LABEL_RULE_VERSION
from amfe.io.bedfile import read_bed
from amfe.model.averages import compliance_and_constants
from amfe.model.scales import SCALES, record_seed
from amfe.vocab import CONSTANT_NAMES

pytestmark = pytest.mark.mpi

SEED, COUNT = 11, 12
# Stored in the table or recomputed from the regenerated bed: equal bit for bit.
SAME = ("images", "bond_images", "labels", "C", "density", "index", "seed", "status", "reason",
        "n_particles", "n_removed", "n_bonds", "volume")


def read(path):
    with h5py.File(path, "r") as f:
        rows = {k: (f[k].asstr()[()] if f[k].dtype.kind == "O" else f[k][()])
                for k in f if isinstance(f[k], h5py.Dataset)}
        rows["params"] = {n: f["params"][n][()] for n in f.get("params", {})}
        rows["attrs"] = dict(f.attrs)
    return rows


def ok(proc):
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """(data set made by `amfe dataset`, its label table)."""
    d = tmp_path_factory.mktemp("labels")
    data, table = d / "made.h5", d / "tiny_labels.h5"
    ok(run_cli(["dataset", "-o", str(data), "--count", str(COUNT), "--seed", str(SEED),
                "--scale", "tiny", "--max-failed-share", "1", "--no-progress"]))
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(table)]))
    return data, table


def assert_rebuilt(original, rebuilt, rows=slice(None)):
    a, b = read(original), read(rebuilt)
    for key in SAME:
        x, y = a[key][rows], b[key]
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), key
        if x.dtype.kind == "f":
            assert x.tobytes() == y.tobytes(), key   # bit for bit, NaNs included
    for name, x in a["params"].items():
        assert x[rows].tobytes() == b["params"][name].tobytes(), name
    assert [kept_solver(s) for s in a["solver"][rows]] == list(b["solver"])
    assert np.all(b["iterations"] == -1) and np.all(b["seconds"][:, 2] == 0)   # not kept
    assert b["attrs"]["from_labels"] and b["attrs"]["label_rule_version"] == LABEL_RULE_VERSION


def test_table_layout_and_same_bytes(made, tmp_path):
    data, table = made
    rows, tab = read(data), read(table)
    a = tab["attrs"]
    assert a["format"] == "amfe.labels" and a["scale"] == "tiny" and a["dataset_seed"] == SEED
    assert {"amfe_version", "rtol", "solver", "label_rule_version", "imaging_version"} <= set(a)
    assert tab["C"].shape == (COUNT, 6, 6) and tab["C"].dtype == np.float64
    assert tab["C"].tobytes() == rows["C"].tobytes()
    assert np.array_equal(tab["bed_seed"], [record_seed(SEED, k) for k in range(COUNT)])
    failed = rows["status"] != 0
    assert failed.any() and not failed.all()
    # an empty bed has no digest; the others are 32 hex digits
    digests = tab["bed_digest"].astype(str)
    assert all((d == "") == (n < 0) for d, n in zip(digests, rows["n_particles"]))
    assert all(len(d) == 32 for d in digests[rows["n_particles"] >= 0])
    assert all(json.loads(s)["method"] for s in tab["solver"][~failed])
    assert table.stat().st_size < MAX_TABLE_BYTES
    # the same records give the same bytes (no dates, track_times off)
    again = tmp_path / "again_labels.h5"
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(again)]))
    assert again.read_bytes() == table.read_bytes()
    # a table is written once
    proc = run_cli(["dataset", "--export-labels", str(data), "-o", str(again)])
    assert proc.returncode == 2 and "written once" in proc.stderr


def test_rebuild_equals_the_made_data_set_and_passes_check(made, tmp_path):
    data, table = made
    out = tmp_path / "rebuilt.h5"
    proc = ok(run_cli(["dataset", "--from-labels", str(table), "-o", str(out),
                       "--max-failed-share", "1", "--no-progress"], ranks=2))
    assert "0 % of rank time in the solver" in proc.stdout
    assert_rebuilt(data, out)
    check = run_cli(["dataset", "--check", str(out)])
    assert check.returncode == 0 and "is valid" in check.stdout


def test_shards_join_and_count_takes_the_first_records(made, tmp_path):
    """Shards exported into a directory join; --count M rebuilds records 0..M-1."""
    data, _ = made
    shards = tmp_path / "labels"
    shards.mkdir()
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(shards), "--count", "5"]))
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(shards)]))
    names = sorted(p.name for p in shards.iterdir())
    assert names == [f"tiny_seed{SEED}_labels_00000000-00000005.h5",
                     f"tiny_seed{SEED}_labels_00000005-{COUNT:08d}.h5"]
    proc = run_cli(["dataset", "--export-labels", str(data), "-o", str(shards)])
    assert proc.returncode == 2 and "nothing to export" in proc.stderr
    out = tmp_path / "first.h5"
    proc = run_cli(["dataset", "--from-labels", str(shards / names[0]), "-o", str(out),
                    "--seed", "3"])
    assert proc.returncode == 2 and "--seed from its tables" in proc.stderr
    # the first shard alone cannot make a data set of more than its records
    proc = run_cli(["dataset", "--from-labels", str(shards / names[1]), "-o", str(out)])
    assert proc.returncode == 2 and "records 0.." in proc.stderr and not out.exists()
    args = ["dataset", "--from-labels", *(str(shards / n) for n in names), "-o", str(out),
            "--max-failed-share", "1", "--no-progress"]
    ok(run_cli(args + ["--count", "4"]))
    assert_rebuilt(data, out, slice(0, 4))


def test_solve_rest_continues_a_labelling_run_from_its_tables(made, tmp_path):
    """--from-labels SHARD --solve-rest --count M: the shard's records rebuilt, the rest
    solved with the tables' method; the result's labels equal the run that solved all,
    and its next shard is the bytes of that run's."""
    data, _ = made
    shards, whole = tmp_path / "labels", tmp_path / "whole"
    shards.mkdir()
    whole.mkdir()
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(shards), "--count", "5"]))
    first = next(shards.iterdir())
    out = tmp_path / "grown.h5"
    proc = run_cli(["dataset", "--from-labels", str(first), "-o", str(out), "--count", "9"])
    assert proc.returncode == 2 and "--solve-rest" in proc.stderr and not out.exists()
    proc = run_cli(["dataset", "--solve-rest", "-o", str(out), "--count", "9"])
    assert proc.returncode == 2 and "--from-labels" in proc.stderr
    ok(run_cli(["dataset", "--from-labels", str(first), "--solve-rest", "-o", str(out),
                "--count", str(COUNT), "--max-failed-share", "1", "--no-progress"], ranks=2))
    a, b = read(data), read(out)
    for key in SAME:
        x, y = a[key], b[key]
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), key
        assert x.dtype.kind == "O" or x.tobytes() == y.tobytes(), key
    assert np.all(b["iterations"][:5] == -1) and np.all(b["seconds"][:5, 2] == 0)
    solved = (b["status"][5:] == 0)
    assert solved.any() and np.all(b["seconds"][5:, 2][solved] > 0)
    assert b["attrs"]["solved_from"] == 5
    ok(run_cli(["dataset", "--export-labels", str(out), "-o", str(shards)]))
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(whole), "--count", "5"]))
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(whole)]))
    name = f"tiny_seed{SEED}_labels_00000005-{COUNT:08d}.h5"
    assert (shards / name).read_bytes() == (whole / name).read_bytes()


def tampered(table, dest, change):
    shutil.copyfile(table, dest)
    with h5py.File(dest, "r+") as f:
        change(f)
    return dest


def test_a_table_whose_beds_do_not_regenerate_is_refused(made, tmp_path):
    """Refused naming the record; the parts written are kept, and the run resumes from them."""
    data, table = made
    rows = read(data)
    k = int(np.flatnonzero(rows["status"] == 0)[-1])

    def wrong_digest(f):
        d = f["bed_digest"][()]
        d[k] = b"0" * 32
        f["bed_digest"][...] = d
    (tmp_path / "bad").mkdir()
    bad = tampered(table, tmp_path / "bad" / table.name, wrong_digest)
    out = tmp_path / "bad.h5"
    args = ["-o", str(out), "--max-failed-share", "1", "--no-progress"]
    proc = run_cli(["dataset", "--from-labels", str(bad), *args], ranks=2)
    assert proc.returncode == 2, proc.stderr
    assert f"record {k} (bed seed {rows['seed'][k]})" in proc.stderr
    assert "does not regenerate" in proc.stderr
    assert proc.stderr.count("does not regenerate") == 1 and not out.exists()
    kept = sorted(p.name for p in (tmp_path / "bad.h5.parts").glob("rec_*.npz"))
    assert kept and f"rec_{k:08d}.npz" not in kept
    # the same run with the good table (same name, so the same run) keeps those parts
    proc = ok(run_cli(["dataset", "--from-labels", str(table), *args[:-1]], ranks=2))
    assert f"{len(kept)} done before" in proc.stderr
    assert_rebuilt(data, out)


@pytest.mark.parametrize("attr,words", [("imaging_version", "imaging version"),
                                        ("label_rule_version", "label rule")])
def test_another_imaging_or_label_rule_is_refused(made, tmp_path, attr, words):
    _, table = made
    bad = tampered(table, tmp_path / "old_labels.h5", lambda f: f.attrs.update({attr: 99}))
    out = tmp_path / "old.h5"
    proc = run_cli(["dataset", "--from-labels", str(bad), "-o", str(out)])
    assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists() and not (tmp_path / "old.h5.parts").exists()


def test_resolving_three_records_tightly_agrees_with_the_table(made, tmp_path):
    """The label contract: a GAMG solve at rtol 1e-10 within 1e-5 of the stored labels."""
    _, table = made
    tab = read(table)
    for k in np.flatnonzero(tab["status"] == 0)[:3]:
        bed_path, res = tmp_path / f"bed{k}.h5", tmp_path / f"r{k}.json"
        ok(run_cli(["pack", "--scale", "tiny", "--seed", str(tab["bed_seed"][k]),
                    "-o", str(bed_path)]))
        assert bed_digest(read_bed(bed_path)) == tab["bed_digest"][k].decode()
        ok(run_cli(["homogenize", str(bed_path), "--solver", "gamg", "--rtol", "1e-10",
                    "-o", str(res)]))
        tight = json.loads(res.read_text())["properties"]
        stored = compliance_and_constants(tab["C"][k])[1]
        err = max(abs(tight[n] - stored[n]) / abs(tight[n]) for n in CONSTANT_NAMES)
        assert len(CONSTANT_NAMES) == 9 and err < 1e-5, (k, err)


def test_export_refuses_a_data_set_whose_beds_do_not_regenerate(made, tmp_path):
    data, _ = made
    rows = read(data)
    k = int(np.flatnonzero(rows["n_particles"] > 0)[0])

    def other_count(f):
        n = f["n_particles"][()]
        n[k] += 1
        f["n_particles"][...] = n
    bad = tampered(data, tmp_path / "other.h5", other_count)
    proc = run_cli(["dataset", "--export-labels", str(bad), "-o", str(tmp_path / "t_labels.h5")])
    assert proc.returncode == 2 and f"record {k} " in proc.stderr
    assert not (tmp_path / "t_labels.h5").exists()


def test_medium_scale_has_the_small_scale_distribution():
    small, medium = SCALES["small"], SCALES["medium"]
    assert medium.size == pytest.approx((1.2e-3, 1.2e-3, 0.3e-3))
    assert medium.image_shape == (3, 40, 40)
    same = {k: v for k, v in vars(small).items() if k not in ("name", "size", "purpose")}
    assert same == {k: v for k, v in vars(medium).items() if k not in ("name", "size", "purpose")}
    assert set(IDENTITY) >= {"scale", "dataset_seed", "imaging_version", "label_rule_version"}

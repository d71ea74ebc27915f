"""`amfe dataset --count M` on a finished data set of N < M records: it grows.

Record k is a pure function of (seed, k) and the method, so the grown file must
equal, in every HDF5 dataset and every attribute that is not a timing, the file
made in one go with M records; its first N rows must be the old file's, bit for
bit (timings included: they are copied, not recomputed); only records N..M-1 are
solved; and until the grown file is whole, the old one stays as it was.
"""
import glob
import hashlib
import json
import os
import shutil
import subprocess
import time

import h5py
import numpy as np
import pytest
from helpers import MPI_ENV, ROOT
from test_dataset import _kill_session, dataset_cmd, remove_stale_lock

import amfe.dataset.driver as driver
import amfe.dataset.merge as merge
from amfe.cli import main
from amfe.dataset.lock import lock_path
from amfe.dataset.parts import parts_dir

pytestmark = pytest.mark.mpi

SEED, FIRST, BIG = 13, 3, 7
ARGS = ["--seed", str(SEED), "--scale", "tiny", "--no-progress", "--max-failed-share", "1"]
#: Attributes and datasets that hold wall times, or when the file was written.
TIMINGS = {"created", "seconds"}


class Killed(BaseException):
    """A kill, as far as the run can tell: nothing catches it."""


def make(path, count, *extra):
    assert main(["dataset", "-o", str(path), "--count", str(count), *ARGS, *extra]) == 0


def untimed(solver):
    """The solver records (JSON strings) without their wall times (*_seconds)."""
    return np.array([json.dumps({k: v for k, v in json.loads(s).items()
                                 if not k.endswith("_seconds")}) if s else s for s in solver])


def contents(path):
    """{name: value} of every dataset and attribute of an HDF5 file (its groups' too),
    without timings: the solver record's *_seconds keys are dropped."""
    out = {}

    def visit(name, obj):
        for key, value in obj.attrs.items():
            if key not in TIMINGS:
                out[f"{name}@{key}"] = value
        if isinstance(obj, h5py.Dataset) and name not in TIMINGS:
            value = obj.asstr()[()] if obj.dtype.kind == "O" else obj[()]
            out[name] = untimed(value) if name == "solver" else value

    with h5py.File(path, "r") as f:
        visit("/", f)
        f.visititems(visit)
    return out


def assert_same(a, b):
    ca, cb = contents(a), contents(b)
    assert sorted(ca) == sorted(cb)
    for name in ca:
        x, y = np.asarray(ca[name]), np.asarray(cb[name])
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


def rows(path, n=None):
    """Every dataset of a data-set file (timings included), its first n rows."""
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                value = obj.asstr()[()] if obj.dtype.kind == "O" else obj[()]
                out[name] = value[:n]
        f.visititems(visit)
    return out


def digest(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A finished data set of FIRST records, and the one of BIG records made in one go."""
    d = tmp_path_factory.mktemp("grow")
    small, whole = d / "small.h5", d / "whole.h5"
    make(small, FIRST)
    make(whole, BIG)
    with h5py.File(small, "r") as f:
        assert int(f.attrs["count"]) == FIRST
    return small, whole


def _spy(monkeypatch, stop_after=None):
    """Record which records are made; with stop_after, die (as a kill would) after that many."""
    seen, real = [], driver.make_record

    def make_record(k, *args, **kwargs):
        if stop_after is not None and len(seen) == stop_after:
            raise Killed("killed")
        seen.append(k)
        return real(k, *args, **kwargs)
    monkeypatch.setattr(driver, "make_record", make_record)
    return seen


def test_a_finished_file_grows_to_the_file_made_in_one_go(made, tmp_path, monkeypatch, capsys):
    small, whole = made
    grown = tmp_path / "grown.h5"
    shutil.copy(small, grown)
    seen = _spy(monkeypatch)
    make(grown, BIG)
    assert sorted(seen) == list(range(FIRST, BIG))          # only the new records solved
    captured = capsys.readouterr()
    assert f"holds {FIRST} records and grows to {BIG}" in captured.err
    assert f"this run {BIG - FIRST} beds" in captured.out
    assert_same(grown, whole)
    old, new = rows(small), rows(grown, FIRST)              # the first run's rows, bit for bit
    assert sorted(old) == sorted(new)
    for name in old:                                        # timings too: copied, not redone
        assert np.array_equal(old[name], new[name], equal_nan=old[name].dtype.kind == "f"), name
    assert not os.path.exists(parts_dir(grown)) and not os.path.exists(lock_path(grown))
    assert main(["dataset", "--check", str(grown)]) == 0
    # the same count again: nothing to do, the file untouched
    before = os.stat(grown).st_mtime_ns
    make(grown, BIG)
    assert "already complete" in capsys.readouterr().out
    assert os.stat(grown).st_mtime_ns == before


def test_a_grow_killed_while_solving_keeps_the_old_file_and_resumes(made, tmp_path, monkeypatch,
                                                                    capsys):
    small, whole = made
    grown = tmp_path / "grown.h5"
    shutil.copy(small, grown)
    old = digest(grown)
    seen = _spy(monkeypatch, stop_after=2)
    with pytest.raises(Killed):
        make(grown, BIG)
    assert digest(grown) == old                             # the old file as it was
    kept = sorted(glob.glob(os.path.join(parts_dir(grown), "rec_*.npz")))
    assert len(kept) == 2 and seen == [FIRST, FIRST + 1]
    # a reader sees the old, finished file meanwhile
    assert main(["dataset", "--check", str(grown)]) == 0
    assert f"{FIRST} records" in capsys.readouterr().out
    # its own count again: complete, and the grow's records are kept for the grow
    make(grown, FIRST)
    assert "already complete" in capsys.readouterr().out
    assert sorted(glob.glob(os.path.join(parts_dir(grown), "rec_*.npz"))) == kept
    # --prefix-of of a growing file: its rows, then the new records finished in a row
    first = tmp_path / "first.h5"
    assert main(["dataset", "--prefix-of", str(grown), "-o", str(first)]) == 0
    a, b = rows(first), rows(whole, FIRST + 2)
    a["solver"], b["solver"] = untimed(a["solver"]), untimed(b["solver"])
    for name in a:
        if name != "seconds":
            assert np.array_equal(a[name], b[name], equal_nan=a[name].dtype.kind == "f"), name
    assert digest(grown) == old and len(kept) == 2
    monkeypatch.undo()
    seen = _spy(monkeypatch)
    make(grown, BIG)                                        # the same command resumes
    assert seen == list(range(FIRST + 2, BIG))
    assert_same(grown, whole)
    assert not os.path.exists(parts_dir(grown))


def test_a_grow_killed_while_merging_keeps_the_old_file_and_resumes(made, tmp_path,
                                                                    monkeypatch):
    small, whole = made
    grown = tmp_path / "grown.h5"
    shutil.copy(small, grown)
    old = digest(grown)
    real = merge.atomic_write_h5

    def killed(path, fill, **kwargs):   # the grown file written, killed before its rename
        with h5py.File("scratch", "w", driver="core", backing_store=False) as f:
            fill(f)
        raise Killed("killed")
    monkeypatch.setattr(merge, "atomic_write_h5", killed)
    with pytest.raises(Killed):
        make(grown, BIG)
    assert digest(grown) == old
    assert len(glob.glob(os.path.join(parts_dir(grown), "rec_*.npz"))) == BIG - FIRST
    monkeypatch.setattr(merge, "atomic_write_h5", real)
    seen = _spy(monkeypatch)
    make(grown, BIG)
    assert seen == []                                       # nothing solved again: merged
    assert_same(grown, whole)


def test_a_grow_under_mpirun_killed_resumes(made, tmp_path):
    """2 ranks, SIGKILL of the whole job while it grows, then the same command."""
    small, _ = made
    big = 40
    grown = tmp_path / "grown.h5"
    shutil.copy(small, grown)
    old = digest(grown)
    parts = parts_dir(grown)
    proc = subprocess.Popen(dataset_cmd(grown, count=big, seed=SEED, ranks=2,
                                        extra=["--no-progress"]),
                            cwd=ROOT, env=MPI_ENV, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.time()
        while len(glob.glob(os.path.join(parts, "rec_*.npz"))) < 3:
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.time() - t0 < 120
            time.sleep(0.02)
    finally:
        _kill_session(proc)   # mpirun and every rank (Open MPI gives each its own group)
    n = len(glob.glob(os.path.join(parts, "rec_*.npz")))
    assert 3 <= n < big - FIRST
    assert digest(grown) == old
    remove_stale_lock(grown)
    r = subprocess.run(dataset_cmd(grown, count=big, seed=SEED, ranks=2, extra=["--no-progress"]),
                       capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"this run {big - FIRST - n} beds" in r.stdout
    once = tmp_path / "once.h5"
    r = subprocess.run(dataset_cmd(once, count=big, seed=SEED, ranks=2, extra=["--no-progress"]),
                       capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    a, b = rows(grown), rows(once)
    for name in ("index", "seed", "status", "reason", "images", "bond_images", "density",
                 "n_particles", "params/E", "params/hatch_spacing"):
        assert np.array_equal(a[name], b[name], equal_nan=a[name].dtype.kind == "f"), name
    ok = a["status"] == 0   # labels: beds solved by either rank (the same single-rank solve)
    assert np.array_equal(a["labels"][ok], b["labels"][ok])
    assert np.array_equal(a["images"][:FIRST], rows(small)["images"])


@pytest.mark.parametrize("change, named", [
    ({"--seed": "14"}, "seed 13 (asked 14)"),
    ({"--rtol": "1e-8"}, "rtol 1e-07 (asked 1e-08)"),
    ({"--solver": "gamg"}, "solver auto (asked gamg)"),
    ({"--bc": "mixed"}, "bc kubc (asked mixed)"),
    ({"--scale": None, "--size": "0.15 0.15 0.1"}, "scale tiny (asked box150x150x100um)"),
    ({"--scale": None, "--size": "0.15 0.15 0.1", "--materials": "draw"},
     "scale tiny (asked box150x150x100um_nu250to400psi40to120)"),
])
def test_a_grow_with_other_parameters_is_refused(made, tmp_path, capsys, change, named):
    small, _ = made
    path = tmp_path / "f.h5"
    shutil.copy(small, path)
    old = digest(path)
    options = {"--seed": str(SEED), "--scale": "tiny", **change}
    args = [w for k, v in options.items() if v is not None for w in (k, *v.split())]
    assert main(["dataset", "-o", str(path), "--count", str(BIG), *args, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "other parameters" in err and named in err, err
    assert digest(path) == old and not os.path.exists(parts_dir(path))


def test_a_grow_across_imaging_versions_is_refused(made, tmp_path, capsys):
    small, _ = made
    path = tmp_path / "f.h5"
    shutil.copy(small, path)
    with h5py.File(path, "r+") as f:
        f.attrs["imaging_version"] = 0
    assert main(["dataset", "-o", str(path), "--count", str(BIG), *ARGS]) == 2
    err = capsys.readouterr().err
    assert "imaging_version 0 (this amfe makes 1)" in err, err


def test_fewer_records_point_at_prefix_of_which_takes_them(made, tmp_path, capsys):
    small, whole = made
    path = tmp_path / "f.h5"
    shutil.copy(whole, path)
    old = digest(path)
    assert main(["dataset", "-o", str(path), "--count", str(FIRST), *ARGS]) == 2
    err = capsys.readouterr().err
    assert f"holds {BIG} records" in err and f"--prefix-of {path}" in err, err
    assert digest(path) == old
    first = tmp_path / "first.h5"
    assert main(["dataset", "--prefix-of", str(path), "-o", str(first),
                 "--count", str(FIRST)]) == 0
    a, b = contents(first), contents(small)
    assert a.pop("/@prefix_of") == f"{path} (count {BIG})"
    assert sorted(a) == sorted(b)
    for name in a:
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name]),
                              equal_nan=np.asarray(a[name]).dtype.kind == "f"), name

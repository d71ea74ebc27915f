"""`amfe dataset`: determinism across rank counts, labels = amfe homogenize, kill + resume,
failed records, --check, and `amfe pack --scale`.

The beds come from the `tiny` scale (amfe.model.scales; for tests only): 0.15 x 0.15 x
0.1 mm beds of a few hundred particles, a fifth of them empty on purpose so
that failed records are exercised.
"""
import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, run_cli

from amfe.cli import main
from amfe.dataset.lock import DatasetLock
from amfe.dataset.parts import PARAMS_JSON, parts_dir
from amfe.errors import AmfeError
from amfe.io.bedfile import read_bed
from amfe.model.bed import generate_bed
from amfe.model.scales import (
    PARAM_NAMES,
    SCALES,
    bed_for,
    param_record,
    record_seed,
    sample_bed_params,
)
from amfe.vocab import LABEL_NAMES

pytestmark = pytest.mark.mpi

SEED = 5
COUNT = 24        # determinism runs
KILL_COUNT = 150  # kill + resume run: a few seconds on 2 ranks
EMPTY_REASON = "the scan path deletes every particle"
ROW_KEYS = ("images", "bond_images", "labels", "C", "density", "index", "seed", "status", "reason",
            "iterations", "n_particles", "n_removed", "n_bonds", "volume")


def dataset_cmd(out, count=COUNT, seed=SEED, ranks=None, extra=()):
    """The `amfe dataset` command line; the tiny scale fails a fifth of its beds on purpose."""
    cmd = [sys.executable, "-m", "amfe.cli", "dataset", "-o", str(out), "--count", str(count),
           "--seed", str(seed), "--scale", "tiny", "--max-failed-share", "1", *extra]
    return ["mpirun", "-n", str(ranks), *cmd] if ranks else cmd


def read_rows(path):
    with h5py.File(path, "r") as f:
        rows = {k: (f[k].asstr()[()] if f[k].dtype.kind == "O" else f[k][()]) for k in ROW_KEYS}
        rows["params"] = {n: f["params"][n][()] for n in f["params"]}
        rows["attrs"] = dict(f.attrs)
    return rows


def assert_same_records(a, b, rows=slice(None), rtol=1e-9):
    """Same records: images, seeds, statuses exactly; labels and C to rtol."""
    for key in ROW_KEYS:
        x, y = a[key][rows], b[key][rows]
        if key == "volume":
            ok = np.isfinite(x)
            assert np.array_equal(ok, np.isfinite(y)), key
            assert np.allclose(x[ok], y[ok], rtol=rtol, atol=0), key
        elif key == "labels":  # moduli relative, Poisson ratios (O(0.1)) absolute
            ok = np.isfinite(x).all(axis=1)
            assert np.array_equal(ok, np.isfinite(y).all(axis=1))
            assert np.allclose(x[ok, :3], y[ok, :3], rtol=rtol, atol=0), key
            assert np.allclose(x[ok, 3:], y[ok, 3:], rtol=0, atol=rtol), key
        elif key == "C":  # relative to each record's largest entry
            ok = np.isfinite(x).all(axis=(1, 2))
            assert np.array_equal(ok, np.isfinite(y).all(axis=(1, 2)))
            scale = np.abs(x[ok]).max(axis=(1, 2), keepdims=True)
            assert np.all(np.abs(x[ok] - y[ok]) <= rtol * scale), key
        elif key == "iterations":
            continue  # solver round-off may change an iteration count across group sizes
        else:
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), key


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same (seed, count) on 1 rank and on 2 ranks (2 groups of 1)."""
    d = tmp_path_factory.mktemp("ds")
    out = {}
    for ranks in (1, 2):
        path = d / f"r{ranks}.h5"
        proc = subprocess.run(dataset_cmd(path, ranks=ranks if ranks > 1 else None),
                              capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=300)
        assert proc.returncode == 0, proc.stderr[-3000:]
        out[ranks] = (path, proc)
    return out


def test_same_records_on_1_and_2_ranks(runs):
    a, b = read_rows(runs[1][0]), read_rows(runs[2][0])
    assert_same_records(a, b)
    assert np.array_equal(a["index"], np.arange(COUNT))
    assert [int(s) for s in a["seed"]] == [record_seed(SEED, k) for k in range(COUNT)]
    for name in PARAM_NAMES:
        assert np.array_equal(a["params"][name], b["params"][name], equal_nan=True)
    assert a["images"].shape == (COUNT, *SCALES["tiny"].image_shape)
    assert a["labels"].shape == (COUNT, 6) and a["C"].shape == (COUNT, 6, 6)
    assert list(a["attrs"]["label_names"]) == list(LABEL_NAMES)
    assert a["attrs"]["scale"] == "tiny" and a["attrs"]["seed"] == SEED
    assert a["attrs"]["count"] == COUNT
    # the parts directory is gone once the file is merged
    assert not os.path.exists(parts_dir(runs[1][0]))


def test_progress_bar_and_summary(runs):
    for ranks, (path, proc) in runs.items():
        assert f"{COUNT}/{COUNT}" in proc.stderr           # tqdm bar, rank 0 only
        assert proc.stderr.count("amfe dataset: tiny:") == 1
        assert "bed/s" in proc.stderr or "s/bed" in proc.stderr
        assert f"{COUNT} beds" in proc.stdout and "beds/hour" in proc.stdout
        assert "packing density (mean of the image)" in proc.stdout
        assert proc.stdout.count("beds/hour") == 1          # one summary line, rank 0 only


def test_failed_records_are_recorded_not_fatal(runs):
    rows = read_rows(runs[1][0])
    empty = np.array([param_record(sample_bed_params("tiny", int(s)))["empty"] == 1.0
                      for s in rows["seed"]])
    assert empty.any() and not empty.all(), "pick a SEED whose records include empty beds"
    assert np.array_equal(rows["params"]["empty"] == 1.0, empty)
    failed = rows["status"] == 1
    # the empty beds fail in generation; a few tiny beds fail in the solve (a sliver of a
    # track: no bonds, or too few particles to span a volume); every other record is ok
    assert np.all(failed[empty])
    assert all(EMPTY_REASON in r for r in rows["reason"][empty])
    assert all(r and EMPTY_REASON not in r for r in rows["reason"][failed & ~empty])
    assert all(r == "" for r in rows["reason"][~failed])
    assert (~failed).sum() >= COUNT // 2
    assert np.isnan(rows["labels"][failed]).all() and np.isnan(rows["C"][failed]).all()
    assert np.isfinite(rows["labels"][~failed]).all()
    assert (rows["labels"][~failed, :3] > 0).all()
    assert np.isnan(rows["density"][empty]).all() and (rows["n_particles"][empty] == -1).all()
    d = rows["density"][~failed]
    assert np.all((d > 0) & (d < 1))
    assert np.allclose(d, rows["images"][~failed].mean(axis=(1, 2, 3)), rtol=1e-6)
    n_failed, n_empty = int(failed.sum()), int(empty.sum())
    line = runs[1][1].stdout
    assert f"{n_failed} failed (" in line and f"{n_empty} x {EMPTY_REASON}" in line


def test_labels_equal_amfe_homogenize_of_regenerated_bed(runs, tmp_path, capsys):
    rows = read_rows(runs[1][0])
    k = int(np.flatnonzero(rows["status"] == 0)[1])
    seed = int(rows["seed"][k])
    bed_path = tmp_path / "bed.h5"
    assert main(["pack", "--scale", "tiny", "--seed", str(seed), "-o", str(bed_path)]) == 0
    assert f"bed seed {seed}" in capsys.readouterr().out
    bed = read_bed(bed_path)
    ref = bed_for("tiny", seed)
    assert np.array_equal(bed.centers, ref.centers) and np.array_equal(bed.radii, ref.radii)
    assert bed.n == rows["n_particles"][k]
    res = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(bed_path), "-o", str(res)])
    assert proc.returncode == 0, proc.stderr
    props = json.loads(res.read_text())["properties"]
    want = np.array([props[n] for n in LABEL_NAMES])
    assert np.allclose(rows["labels"][k], want, rtol=1e-8, atol=0)
    # the record's image is the regenerated bed's, with the attrs' recipe
    from amfe.dataset.images import pixelate
    a = rows["attrs"]
    img = pixelate(bed, cell=tuple(a["image_cell"][:2]), layer_thickness=a["layer_thickness"],
                   box=((0.0, 0.0, 0.0), tuple(a["bed_size"])), spacing=a["image_spacing"])
    assert np.array_equal(img, rows["images"][k])


def test_bond_images_equal_those_of_regenerated_beds(runs, tmp_path, capsys):
    """--add-bond-images (regeneration from the seeds) rebuilds what the run recorded."""
    src = runs[1][0]
    with h5py.File(src, "r") as f:
        made = f["bond_images"][()]
        status = f["status"][()]
    assert made[status == 0].min() >= 0 and made[status == 0].sum(axis=(1, 2, 3)).min() > 0
    old = tmp_path / "old.h5"
    with h5py.File(src, "r") as f, h5py.File(old, "w") as g:   # a file from before bond images
        for name in f:
            if name != "bond_images":
                f.copy(f[name], g, name)
        g.attrs.update(dict(f.attrs))
    assert main(["dataset", "--add-bond-images", str(old), "--no-progress"]) == 0
    assert f"added /bond_images of {COUNT} records" in capsys.readouterr().out
    with h5py.File(old, "r") as g:
        assert np.array_equal(g["bond_images"][()], made)
    assert main(["dataset", "--check", str(old)]) == 0
    capsys.readouterr()
    assert main(["dataset", "--add-bond-images", str(old)]) == 2
    assert "already has /bond_images" in capsys.readouterr().err


def _session_pids(sid):
    """Pids of the live processes in session ``sid`` (mpirun and the ranks it started)."""
    pids = []
    for stat in glob.glob("/proc/[0-9]*/stat"):
        try:
            with open(stat) as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            pids.append(int(stat.split("/")[2]))
    return pids


def _kill_session(proc):
    """SIGKILL every process of ``proc``'s session (Open MPI gives each rank its own group)."""
    for _ in range(100):
        pids = _session_pids(proc.pid)
        if not pids:
            break
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.05)
    proc.wait()
    assert not _session_pids(proc.pid)


def _start_and_kill(out, parts, at_least, how, extra=()):
    """Start the 2-rank run, SIGKILL it (one rank, or the whole session) once parts exist."""
    proc = subprocess.Popen(dataset_cmd(out, count=KILL_COUNT, ranks=2,
                                        extra=["--no-progress", *extra]),
                            cwd=ROOT, env=MPI_ENV, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.time()
        while len(glob.glob(os.path.join(parts, "rec_*.npz"))) < at_least:
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.time() - t0 < 120
            time.sleep(0.02)
        if how == "rank":
            ranks = [p for p in _session_pids(proc.pid) if p != proc.pid]
            assert len(ranks) == 2
            os.kill(max(ranks), signal.SIGKILL)   # one rank; mpirun must end the job
            proc.wait(timeout=60)
            assert proc.returncode != 0
    finally:
        _kill_session(proc)   # the whole job (or what is left of it)
    n = len(glob.glob(os.path.join(parts, "rec_*.npz")))
    assert at_least <= n < KILL_COUNT
    assert not out.exists()
    remove_stale_lock(out)
    return n


def remove_stale_lock(out):
    """After a kill: the lock left behind (if any) is reported stale, with the rm command."""
    lock = DatasetLock(out)
    if not os.path.exists(lock.path):
        return False
    with pytest.raises(AmfeError, match="stale lock") as err:
        lock.acquire()
    assert f"rm {lock.path}" in str(err.value)
    os.remove(lock.path)
    return True


def test_kill_and_resume(runs, tmp_path):
    out = tmp_path / "k.h5"
    parts = parts_dir(out)
    # 1. SIGKILL one rank of a run of groups of 2 ranks; 2. resume with 2 groups of 1 and
    # SIGKILL the whole job; 3. resume to the end.
    n1 = _start_and_kill(out, parts, 6, "rank", extra=["--ranks-per-bed", "2"])
    n2 = _start_and_kill(out, parts, n1 + 6, "session")
    # A different data set in the same place is refused, the parts are kept.
    r = run_cli(["dataset", "-o", str(out), "--count", str(KILL_COUNT), "--seed", "9",
                 "--scale", "tiny", "--max-failed-share", "1"])
    assert r.returncode == 2 and "other parameters" in r.stderr
    assert len(glob.glob(os.path.join(parts, "rec_*.npz"))) == n2
    r = subprocess.run(dataset_cmd(out, count=KILL_COUNT, ranks=2, extra=["--no-progress"]),
                       capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"{KILL_COUNT} beds" in r.stdout
    done_now = int(r.stdout.split("this run ")[1].split()[0])
    assert done_now == KILL_COUNT - n2   # only the missing records were computed
    assert not os.path.exists(parts)
    rows = read_rows(out)
    assert np.array_equal(rows["index"], np.arange(KILL_COUNT))
    assert [int(s) for s in rows["seed"]] == [record_seed(SEED, k) for k in range(KILL_COUNT)]
    # records equal the uninterrupted runs' (some solved by 2-rank groups: round-off only)
    assert_same_records(rows, read_rows(runs[1][0]), rows=slice(0, COUNT), rtol=1e-6)
    check = run_cli(["dataset", "--check", str(out)])
    assert check.returncode == 0 and f"{KILL_COUNT} records" in check.stdout


def test_rerun_of_a_complete_file_does_nothing(runs, capsys):
    path = runs[1][0]
    before = os.stat(path).st_mtime_ns
    assert main(["dataset", "-o", str(path), "--count", str(COUNT), "--seed", str(SEED),
                 "--scale", "tiny", "--no-progress", "--max-failed-share", "1"]) == 0
    assert "already complete" in capsys.readouterr().out
    assert os.stat(path).st_mtime_ns == before
    # a larger count grows it (tests/test_dataset_grow.py), unless another parameter differs
    assert main(["dataset", "-o", str(path), "--count", str(COUNT + 1), "--seed", str(SEED + 1),
                 "--scale", "tiny", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "other parameters" in err and f"seed {SEED} (asked {SEED + 1})" in err
    assert main(["dataset", "-o", str(path), "--count", str(COUNT - 1), "--seed", str(SEED),
                 "--scale", "tiny", "--no-progress"]) == 2
    assert "--prefix-of" in capsys.readouterr().err
    assert os.stat(path).st_mtime_ns == before


def test_parts_of_another_run_are_refused(tmp_path, capsys):
    out = tmp_path / "p.h5"
    parts = parts_dir(out)
    os.makedirs(parts)
    with open(os.path.join(parts, PARAMS_JSON), "w") as fh:
        json.dump({"scale": "tiny", "seed": 1, "count": 3}, fh)
    assert main(["dataset", "-o", str(out), "--count", "3", "--seed", "2", "--scale", "tiny",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "belongs to a run with other parameters" in err and "seed 1" in err
    assert os.path.exists(os.path.join(parts, PARAMS_JSON))


def test_check(runs, tmp_path, capsys):
    good = runs[1][0]
    assert main(["dataset", "--check", str(good)]) == 0
    out = capsys.readouterr().out
    assert "is valid" in out and f"{COUNT} records" in out and "packing density" in out

    dup = tmp_path / "dup.h5"
    shutil.copy(good, dup)
    with h5py.File(dup, "r+") as f:
        f["index"][3] = 2
    assert main(["dataset", "--check", str(dup)]) == 1
    err = capsys.readouterr().err
    assert "NOT a valid data set" in err
    assert "duplicate record indices: 2" in err and "missing record indices: 3" in err

    short = tmp_path / "short.h5"
    with h5py.File(good, "r") as src, h5py.File(short, "w") as f:
        for k, v in src.attrs.items():
            f.attrs[k] = v
        for name in src:
            if isinstance(src[name], h5py.Dataset):
                f.create_dataset(name, data=src[name][:-1])
    assert main(["dataset", "--check", str(short)]) == 1
    assert f"{COUNT - 1} rows but the count attribute says {COUNT}" in capsys.readouterr().err

    bad = tmp_path / "bad.h5"
    shutil.copy(good, bad)
    with h5py.File(bad, "r+") as f:
        k = int(np.flatnonzero(f["status"][()] == 0)[0])
        f["labels"][k, 0] = np.nan
    assert main(["dataset", "--check", str(bad)]) == 1
    assert "non-finite labels" in capsys.readouterr().err

    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    assert main(["dataset", "--check", str(junk)]) == 2
    assert "not an HDF5 file" in capsys.readouterr().err


def test_scales_are_pure_functions():
    assert record_seed(0, 0) == record_seed(0, 0) != record_seed(0, 1) != record_seed(1, 0)
    assert 0 <= record_seed(7, 123) < 2**32
    p, q = sample_bed_params("small", 42), sample_bed_params("small", 42)
    assert p == q
    assert p["seed"] == 42 and p["size"] == SCALES["small"].size
    assert 1.06 <= p["enlargement"][1] <= 1.14
    assert SCALES["small"].image_shape == (3, 20, 20)
    assert SCALES["paper"].image_shape == (3, 100, 100)
    a, b = generate_bed(**p), bed_for("small", 42)
    assert np.array_equal(a.centers, b.centers) and np.array_equal(a.radii, b.radii)
    # parameters span their documented ranges over a few hundred beds
    recs = [param_record(sample_bed_params("small", record_seed(0, k))) for k in range(300)]
    cov = np.array([r["coverage"] for r in recs])
    assert cov.min() < 0.45 and cov.max() > 0.9
    assert {r["layer_rotation"] for r in recs} == {67.0, 90.0}
    skip = np.array([r["skip_fraction"] for r in recs])
    assert 0.3 < np.mean(skip == 0) < 0.7 and skip.max() <= 0.3


def test_pack_scale_refuses_other_generation_options(tmp_path, capsys):
    out = tmp_path / "b.h5"
    assert main(["pack", "--scale", "small", "--seed", "3", "--size", "1", "1", "0.3",
                 "-o", str(out)]) == 2
    assert "cannot be combined with --size" in capsys.readouterr().err
    assert main(["pack", "--scale", "tiny", "--seed", "1", "--track-width", "0.1",
                 "-o", str(out)]) == 2
    assert "--track-width" in capsys.readouterr().err
    assert not out.exists()

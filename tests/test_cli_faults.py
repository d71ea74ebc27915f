"""Bad input and faults on the command line (issue 18, items 4, 6, 7, 12, 13; issue 16, item 5).

Each test reproduces a command of the issue and checks what amfe does now:
one clear line and exit 2 before any work, never a traceback, a NaN reported
as a result, or a destroyed input.
"""
import errno
import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from cli_fixtures import (
    assert_one_error,
    mutated_checkpoint,
    run_main,
    sha256,
    tiny_dataset,
    tiny_model,
)
from helpers import MPI_ENV, ROOT

from amfe.cli import parse, split_petsc_args

SIX = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """(model.pt, bed.h5, directory) shared by the module's tests (nothing writes to them)."""
    d = tmp_path_factory.mktemp("model")
    m, bed = tiny_model(str(d))
    return str(m), str(bed), d


def _nan_weights(ck):
    for member in ck["members"]:
        for name in member:
            member[name] = member[name] * float("nan")


# ---------------------------------------------------------------- item 4: the surrogate

def test_nan_weights_are_flagged_never_in_distribution(model, tmp_path):
    """`amfe predict bed.h5 --model nan.pt` gave NaN constants "in distribution", exit 0."""
    m, bed, _ = model
    nan = mutated_checkpoint(m, tmp_path / "nan.pt", _nan_weights)
    out = tmp_path / "p.json"
    code, _, err = run_main(["predict", bed, "--model", nan, "-o", out])
    line = assert_one_error(code, err, "predict")
    assert "not finite" in line and "--fallback" in line
    assert not out.exists()
    # the ensemble summary itself flags it, whatever the threshold
    from amfe.training.ensemble import summarize_members
    members = np.ones((2, 3, 6))
    members[1, 1, 4] = np.nan
    res = summarize_members(members, threshold=None)
    assert res["nonfinite"].tolist() == [False, True, False]
    assert res["flagged"].tolist() == [False, True, False]


def test_fallback_solves_a_non_finite_prediction(model, tmp_path):
    """--fallback did not fall back on NaN; now the solver's constants are reported."""
    m, bed, _ = model
    nan = mutated_checkpoint(m, tmp_path / "nan.pt", _nan_weights)
    out = tmp_path / "p.json"
    code, stdout, err = run_main(["predict", bed, "--model", nan, "--fallback", "-o", out])
    assert code == 0, err
    res = json.loads(out.read_text())   # strict JSON: no NaN anywhere
    assert res["flagged"] and "non-finite" in res["flag_reasons"] and res["source"] == "solver"
    assert "in distribution" not in stdout and "not finite" in stdout
    assert all(v is None for v in res["surrogate"]["properties"].values())
    # the constants are the solver's: an independent homogenize_bed of the same bed
    from helpers import homogenize_arrays

    from amfe.io.bedfile import read_bed
    b = read_bed(bed)
    ref = homogenize_arrays(b.centers, b.radii, b.material(), size=b.attrs["size"])["properties"]
    for k in SIX:
        assert math.isfinite(res["properties"][k])
        assert res["properties"][k] == pytest.approx(float(ref[k]), rel=1e-6)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-1", "abc"])
def test_bad_threshold_is_refused(model, value, tmp_path):
    """`--threshold nan` was accepted and the flag could then never fire."""
    m, bed, _ = model
    code, _, err = run_main(["predict", bed, "--model", m, f"--threshold={value}",
                             "-o", tmp_path / "p.json"])
    assert "argument --threshold" in assert_one_error(code, err, "predict")
    assert not (tmp_path / "p.json").exists()


@pytest.mark.parametrize("command", ["predict", "train"])
@pytest.mark.parametrize("value", ["-1", "0", "100000", "two"])
def test_bad_thread_count_is_refused(model, command, value, tmp_path):
    """`--threads -1` gave a traceback from torch."""
    m, bed, d = model
    args = ([bed, "--model", m] if command == "predict"
            else [d / "tiny.h5", "-o", tmp_path / "m.pt"])
    code, _, err = run_main([command, *args, f"--threads={value}"])
    assert "argument --threads" in assert_one_error(code, err, command)
    assert os.listdir(tmp_path) == []


def _set(path, value):
    """A change of one checkpoint field, addressed by a key path."""
    def change(ck):
        obj = ck
        for key in path[:-1]:
            obj = obj[key]
        obj[path[-1]] = value(obj[path[-1]]) if callable(value) else value
    return change


JUNK = {
    "string weights": (_set(("members", 0, "features.0.weight"), "abc"), "is a str"),
    "wrong shape": (_set(("members", 1, "features.0.weight"), lambda w: w[..., :2]),
                    "has shape"),
    "integer weights": (_set(("members", 0, "features.0.bias"), lambda w: w.long()),
                        "floating-point"),
    "member not a dict": (_set(("members", 0), [1, 2]), "not a dict"),
    "missing weight": (lambda ck: ck["members"][0].pop("features.0.bias"), "missing"),
    "image shape text": (_set(("image_shape",), "abc"), "image_shape"),
    "huge image shape": (_set(("image_shape",), [1, 10 ** 6, 10 ** 6]), "do not fit"),
    "NaN threshold": (_set(("spread", "threshold"), float("nan")), "threshold"),
    "zero normalizer std": (_set(("normalizer", "std"), [0.0] * 6), "normalizer std"),
    "pixel spacing 1 pm": (_set(("pixelation", "image_spacing"), 1e-12), "image_spacing"),
    "arch args": (_set(("arch_args", "padding"), "sideways"), "padding"),
    "format version": (_set(("format_version",), "one"), "format_version"),
}


@pytest.mark.parametrize("name", sorted(JUNK))
def test_junk_checkpoint_is_one_clear_error(model, name, tmp_path):
    """Junk checkpoint members (string weights) gave a traceback."""
    m, bed, _ = model
    change, words = JUNK[name]
    junk = mutated_checkpoint(m, tmp_path / "junk.pt", change)
    code, _, err = run_main(["predict", bed, "--model", junk, "-o", tmp_path / "p.json"])
    line = assert_one_error(code, err, "predict")
    assert words in line and "junk.pt" in line
    assert not (tmp_path / "p.json").exists()


# ---------------------------------------------------------------- items 6, 7, 13: paths

def test_output_over_input_is_refused(model, tmp_path):
    """`amfe predict s.h5 -o s.h5` overwrote the bed with JSON and reported success."""
    m, bed, _ = model
    s = tmp_path / "s.h5"
    s.write_bytes(open(bed, "rb").read())
    before = sha256(s)
    for target in (s, tmp_path / "." / "s.h5"):
        code, _, err = run_main(["predict", s, "--model", m, "-o", target])
        assert "also an input" in assert_one_error(code, err, "predict")
    code, _, err = run_main(["predict", s, "--model", m, "-o", m])   # nor over the model
    assert "also an input" in assert_one_error(code, err, "predict")
    assert sha256(s) == before


@pytest.mark.parametrize("where, words", [
    ("/proc/x.json", "cannot write"),
    ("DIR", "is a directory"),
    ("FILE/x.json", "not a directory"),
    ("DIR/missing/x.json", "does not exist"),
])
def test_bad_output_is_refused_before_the_model_is_read(model, tmp_path, where, words):
    """-o /proc/x.json, an existing directory or file/x.json failed after the work, with a
    traceback. Now refused first: the model given here is junk, and the error is the -o one."""
    m, bed, _ = model
    (tmp_path / "DIR").mkdir()
    (tmp_path / "FILE").write_text("x")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a model")
    target = where.replace("DIR", str(tmp_path / "DIR")).replace("FILE", str(tmp_path / "FILE"))
    code, _, err = run_main(["predict", bed, "--model", junk, "-o", target])
    line = assert_one_error(code, err, "predict")
    assert words in line and "-o" in line
    assert sorted(os.listdir(tmp_path)) == ["DIR", "FILE", "junk.pt"]
    assert os.listdir(tmp_path / "DIR") == []


def test_model_directory_is_called_a_directory(model, tmp_path):
    """`--model DIR` said "does not exist"."""
    _, bed, _ = model
    code, _, err = run_main(["predict", bed, "--model", tmp_path])
    assert "is a directory" in assert_one_error(code, err, "predict")


def test_bed_of_another_size_names_the_fix(model, tmp_path):
    """A bed of the wrong size says how to make one the model takes (issue 16, item 5)."""
    from amfe.io.bedfile import write_bed
    from amfe.model.bed import generate_bed
    m, _, _ = model
    wide = tmp_path / "wide.h5"
    write_bed(wide, generate_bed(size=(0.3e-3, 0.15e-3, 0.1e-3), seed=0))
    code, _, err = run_main(["predict", wide, "--model", m])
    line = assert_one_error(code, err, "predict")
    assert "1x5x10" in line and "1x5x5" in line and "`amfe pack --scale tiny`" in line


def test_bed_recording_a_size_of_1_m_is_refused_before_pixelating(model, tmp_path):
    """A `size` attribute of 1 m made predict pixelate a grid of ~10^11 samples (item 11)."""
    import time

    from amfe.io.bedfile import read_bed, write_bed
    m, bed, _ = model
    b = read_bed(bed)
    b.attrs["size"] = [1.0, 1.0, 1.0]
    big = tmp_path / "big.h5"
    write_bed(big, b)
    t0 = time.perf_counter()
    code, _, err = run_main(["predict", big, "--model", m])
    assert "10000x33334x33334" in assert_one_error(code, err, "predict")
    assert time.perf_counter() - t0 < 10


def test_json_to_stdout(model, tmp_path):
    """`-o -` writes the JSON to stdout (issue 16), the table to stderr."""
    m, bed, _ = model
    code, out, err = run_main(["predict", bed, "--model", m, "-o", "-"])
    assert code == 0, err
    res = json.loads(out)
    code, _, _ = run_main(["predict", bed, "--model", m, "-o", tmp_path / "p.json"])
    ref = json.loads((tmp_path / "p.json").read_text())
    assert res["properties"] == ref["properties"] and res["spread"] == ref["spread"]
    assert "source: surrogate" in err and "source" not in out.split("{", 1)[0]
    assert not os.path.exists(os.path.join(os.getcwd(), "-"))


@pytest.mark.parametrize("args, words", [
    (["-o", "/proc/m.pt"], "cannot write -o /proc/m.pt"),
    (["-o", "OUT/m.pt", "--curve", "/proc/c.png"], "cannot write --curve /proc/c.png"),
    (["-o", "OUT/m.pt", "--curve", "OUT/c.txt"], "--curve"),
    (["-o", "OUT/m.pt", "--curve", "OUT/m.pt"], "--curve"),
    (["-o", "OUT/tiny.h5"], ".pt"),
    (["-o", "OUT/m.pt", "--test", "OUT/missing.h5"], "does not exist"),
    (["-o", "OUT/m.pt", "--test", "OUT/other.h5"], "shape"),
    (["-o", "OUT/m.pt", "--lr", "nan"], "--lr"),
    (["-o", "OUT/m.pt", "--val-fraction", "1"], "validation fraction"),
])
def test_train_refuses_bad_paths_before_training(model, tmp_path, args, words):
    """`amfe train -o /proc/m.pt` failed after the whole training run."""
    from test_training import TINY_ATTRS, write_synthetic
    _, _, d = model
    write_synthetic(tmp_path / "other.h5", n=10, shape=(1, 6, 6), attrs=TINY_ATTRS)
    before = sorted(os.listdir(tmp_path))
    args = [a.replace("OUT", str(tmp_path)) for a in args]
    code, out, err = run_main(["train", d / "tiny.h5", *args])
    assert words in assert_one_error(code, err, "train")
    assert not re.search(r"epoch +\d+/|records, \d+ ok", err)   # nothing read or trained
    assert sorted(os.listdir(tmp_path)) == before


def test_train_refuses_too_few_records(tmp_path):
    """`amfe train` on 5 records printed R^2 = nan (1 validation bed)."""
    data = tiny_dataset(tmp_path / "few.h5", n=5, failed=())
    code, _, err = run_main(["train", data, "-o", tmp_path / "m.pt", "--quiet"])
    line = assert_one_error(code, err, "train")
    assert "4 training and 1 validation" in line and "at least 2" in line
    assert not (tmp_path / "m.pt").exists()
    # 10 records: 8 + 2, a finite R^2 for every property
    data = tiny_dataset(tmp_path / "ten.h5", n=10, failed=())
    code, out, err = run_main(["train", data, "-o", tmp_path / "m.pt", "--quiet", "--epochs",
                               "1", "--batch-size", "4"])
    assert code == 0, err
    r2 = out.split("validation R^2:")[1].splitlines()[0].split()[1::2]
    assert len(r2) == 6 and all(math.isfinite(float(v)) for v in r2)


# ---------------------------------------------------------------- options (issue 16, item 5)

def test_mistyped_option_gets_the_subcommand_usage(tmp_path):
    """`amfe homogenize bed.h5 --rtoll 1` printed the top-level usage."""
    code, _, err = run_main(["homogenize", "bed.h5", "--rtoll", "1"])
    line = assert_one_error(code, err, "homogenize")
    assert err.startswith("usage: amfe homogenize") and "--rtoll 1" in line
    # a single dash goes to PETSc where PETSc runs (its unused-option warning names it) ...
    args = parse(["homogenize", "bed.h5", "-foo_bar", "3", "--rtol", "1e-6"])
    assert args.petsc_args == ["-foo_bar", "3"] and args.rtol == 1e-6
    # ... and is refused where it does not: pack, train, predict without a solve
    code, _, err = run_main(["pack", "-seed", "3", "-o", tmp_path / "b.h5"])
    assert "-seed 3" in assert_one_error(code, err, "pack") and err.startswith("usage: amfe pack")
    code, _, err = run_main(["predict", "bed.h5", "-ksp_rtol", "1", "-o", tmp_path / "p.json"])
    assert "--check or --fallback" in assert_one_error(code, err, "predict")
    assert os.listdir(tmp_path) == []


def test_negative_numbers_are_values_not_petsc_options():
    assert split_petsc_args(["--threshold", "-inf", "-ksp_rtol", "-1e-3", "-pc_type", "gamg"]) == (
        ["--threshold", "-inf"], ["-ksp_rtol", "-1e-3", "-pc_type", "gamg"])


# ---------------------------------------------------------------- disk full, broken pipe

def _mount_tmpfs(path, size="64k"):
    path.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                       capture_output=True)
    return r.returncode == 0


def test_full_disk_keeps_the_old_file(model, tmp_path, monkeypatch):
    """A full disk during `predict -o` gave a traceback. On a full tmpfs (or, where mounting is
    not allowed, a write that raises ENOSPC): one line, the old file kept, no temp file."""
    m, bed, _ = model
    disk = tmp_path / "disk"
    mounted = _mount_tmpfs(disk)
    try:
        out = disk / "p.json"
        out.write_text("old result\n")
        if mounted:
            with open(disk / "filler", "wb", buffering=0) as fh:   # fill it to the last byte
                try:
                    while True:
                        fh.write(b"\0" * 4096)
                except OSError as exc:
                    assert exc.errno == errno.ENOSPC
        else:
            import amfe.io.atomic

            def full(*a, **k):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            monkeypatch.setattr(amfe.io.atomic.os, "fsync", full)
        code, _, err = run_main(["predict", bed, "--model", m, "-o", out])
        line = assert_one_error(code, err, "predict")
        # (amfe.io.atomic may say it itself: "no space left on DIR: p.json could not be written")
        assert "no space left" in line.lower() and "p.json" in line
        assert out.read_text() == "old result\n"
        assert sorted(os.listdir(disk)) == (["filler", "p.json"] if mounted else ["p.json"])
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=True)


def test_disk_full_anywhere_is_one_line(monkeypatch, capsys):
    """The last guard in main(): an ENOSPC no command caught is one line and exit 2."""
    import amfe.cli.pack

    def run(args):
        raise OSError(errno.ENOSPC, "No space left on device", "/data/part_3.npz")
    monkeypatch.setattr(amfe.cli.pack, "run", run)
    code, _, err = run_main(["pack"])
    assert "no space left" in assert_one_error(code, err, "pack") and "/data/part_3.npz" in err


@pytest.mark.parametrize("argv", [["-h"], ["predict", "BED", "--model", "MODEL"],
                                  ["homogenize", "BED", "--quiet"]])
def test_broken_pipe_is_quiet(model, argv):
    """`amfe ... | head` ended in a BrokenPipeError traceback (and homogenize, once PETSc ran,
    in PETSc's "Caught signal number 13 Broken Pipe" and MPI_Abort). Run without
    PYTHONUNBUFFERED, as on a fresh machine: `-h` then failed at the interpreter's final flush
    (exit 120, "Exception ignored ... BrokenPipeError"; issue 31)."""
    m, bed, _ = model
    argv = [a.replace("BED", bed).replace("MODEL", m) for a in argv]
    env = {k: v for k, v in MPI_ENV.items() if k != "PYTHONUNBUFFERED"}
    r, w = os.pipe()
    os.close(r)   # the reader is gone before amfe writes
    try:
        p = subprocess.run([sys.executable, "-m", "amfe.cli", *argv], stdout=w,
                           stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env, timeout=120)
    finally:
        os.close(w)
    assert p.returncode == 141 and p.stderr == ""

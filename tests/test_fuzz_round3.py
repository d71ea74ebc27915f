"""Fuzz round three (issue 45, "What must hold"): bad and odd inputs to what the last round
added: the voxel model's options, the Python API (amfe.Bed, SolveOptions through
amfe.homogenize, amfe.Surrogate), label tables (--from-labels, --export-labels) and batch
predict. Every case is a row of CASES below with its expected outcome, written before it
ran (docs/hard_cases.md, "Round three: fuzz"):

- ("error", regex): an AmfeError (API) or exit 2 with one `amfe CMD: error:` line (CLI),
  whose text matches regex; no traceback, no file written, the inputs unchanged;
- ("ok", check): the call returns and check(result) holds: constants equal to the
  reference solve of the same bed (a silent wrong answer would fail it), or the predicted
  batch equal to the single-bed predictions.

A case that ends otherwise (another exception, a traceback, exit 1, a wrong number) fails.
The whole file runs in well under a minute (one 3 x 3 x 3 lattice bed, one tiny model).
"""
import math
import os
import re

import h5py
import numpy as np
import pytest
from cli_fixtures import assert_one_error, run_main, sha256, tiny_model
from helpers import cubic_lattice

import amfe
from amfe.errors import AmfeError
from amfe.io.bedfile import write_bed
from amfe.model.bed import Bed

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARD = os.path.join(ROOT, "labels", "paper_seed22_labels_00000000-00000126.h5")
X, R = cubic_lattice(3)


@pytest.fixture(autouse=True)
def _petsc_options_cleared():
    """Remove the PETSc options a case's command line put in the process's database: they
    would leak into the next call (issue 45, item 3, another helper's; measured here:
    '-ksp_rtol 5' refused the next case and every later test of the session)."""
    import sys
    before = _petsc_options() if "petsc4py.PETSc" in sys.modules else {}
    yield
    if "petsc4py.PETSc" in sys.modules:
        from petsc4py import PETSc
        opts = PETSc.Options()
        for key, value in _petsc_options().items():
            if key not in before:
                opts.delValue(key)
            elif before[key] != value:
                opts.setValue(key, before[key])


def _petsc_options():
    from petsc4py import PETSc
    return dict(PETSc.Options().getAll())


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """{name: path}: the lattice bed, a text file, an empty file, a directory, small label
    shards (records 0-3 of a committed table, and mutations), the tiny model and its bed."""
    d = tmp_path_factory.mktemp("fuzz3")
    out = {"bed": str(d / "bed.h5"), "text": str(d / "t.txt"), "empty": str(d / "e.h5"),
           "dir": str(d / "adir"), "missing": str(d / "nope.h5")}
    write_bed(out["bed"], Bed(X, R))
    open(out["text"], "w").write("hello\n")
    open(out["empty"], "w").close()
    os.mkdir(out["dir"])
    for name, change in SHARD_MUTATIONS.items():
        out[f"shard_{name}"] = _shard(d / f"shard_{name}.h5", change)
    os.mkdir(d / "tiny")
    out["model"], out["tiny_bed"] = map(str, tiny_model(str(d / "tiny")))
    return out


@pytest.fixture(scope="module")
def reference():
    """The lattice bed's constants by the default frame solve, and by the voxel model."""
    return amfe.homogenize(Bed(X, R))


# ---------------------------------------------------------------- label shards

def _shard(path, change):
    with h5py.File(SHARD, "r") as f:
        attrs = dict(f.attrs)
        data = {k: f[k][()][:4] for k in f}
    change(attrs, data)
    with h5py.File(path, "w") as g:
        for k, v in attrs.items():
            g.attrs[k] = v
        for k, v in data.items():
            g[k] = v
    return str(path)


def _set(key, value, where="attrs"):
    def change(attrs, data):
        (attrs if where == "attrs" else data)[key] = value
    return change


def _drop(key):
    def change(attrs, data):
        data.pop(key)
    return change


SHARD_MUTATIONS = {
    "good": lambda a, d: None,
    "format": _set("format", "something else"),
    "no_format": lambda a, d: a.pop("format"),
    "seed": _set("dataset_seed", 23),
    "rtol": _set("rtol", 0.5),
    "label_rule": _set("label_rule_version", 99),
    "imaging": _set("imaging_version", 99),
    "index_shift": lambda a, d: d.__setitem__("index", d["index"] + 1),
    "index_dup": lambda a, d: d.__setitem__("index", np.array([0, 1, 1, 3])),
    "bed_seed": lambda a, d: d.__setitem__("bed_seed", d["bed_seed"] + 1),
    "no_index": _drop("index"),
}


# ---------------------------------------------------------------- the cases

BED = "BED"   # replaced by the lattice bed's path in CLI cases
ERR, OK = "error", "ok"

# amfe.homogenize(bed, model="voxel", **kwargs): the voxel model's options
VOXEL_API = [
    ({"voxel_size": 0.0}, ERR, "positive length"),
    ({"voxel_size": -1e-6}, ERR, "positive length"),
    ({"voxel_size": math.nan}, ERR, "positive length|finite"),
    ({"voxel_size": math.inf}, ERR, "positive length|finite"),
    ({"voxel_size": "abc"}, ERR, "voxel size"),
    ({"voxel_size": True}, ERR, "voxel size"),
    ({"voxel_size": [2e-7]}, ERR, "voxel size"),
    ({"voxel_size": 1j}, ERR, "voxel size"),
    ({"voxel_size": 1e-320}, ERR, "larger --voxel-size"),
    ({"voxel_size": 5e-324}, ERR, "larger --voxel-size"),
    ({"voxel_size": 1e-12}, ERR, "memory"),
    ({"voxel_size": 1e-9}, ERR, "memory"),
    ({"voxel_size": 1.0}, ERR, "necks"),
    ({"voxel_size": 1e300}, ERR, "necks"),
    ({"voxel_size": 2e-6}, ERR, "necks"),
    ({"voxel_size": 1e-12, "voxel_operator": "matrix-free"}, ERR, "memory"),
    ({"voxel_size": 1e-320, "voxel_operator": "matrix-free"}, ERR, "larger --voxel-size"),
    ({"voxel_size": 0.0, "voxel_operator": "matrix-free"}, ERR, "positive length"),
    ({"voxel_size": 1.0, "voxel_operator": "matrix-free"}, ERR, "necks"),
    ({"voxel_operator": "free"}, ERR, "operator"),
    ({"voxel_operator": ""}, ERR, "operator"),
    ({"voxel_operator": None}, ERR, "operator"),
    ({"voxel_operator": 3}, ERR, "operator"),
    ({"voxel_operator": "Matrix-Free"}, ERR, "operator"),
    ({"max_memory": 1}, ERR, "memory"),
    ({"max_memory": 1, "voxel_operator": "matrix-free"}, ERR, "memory"),
    ({"max_memory": 1e6, "voxel_size": 2e-7}, ERR, "memory"),
    ({"max_memory": -5}, ERR, "max_memory|memory"),
    ({"bc": "subc"}, ERR, "voxel model solves"),
    ({"bc": "mixed"}, ERR, "voxel model solves"),
    ({"bc": "all"}, ERR, "voxel|bc"),
    ({"bc": "periodic"}, ERR, "periodic"),
    ({"bc": "KUBC"}, ERR, "bc|boundary"),
    ({"solver": "cholesky"}, ERR, "cholesky|solver"),
    ({"solver": "bogus"}, ERR, "solver"),
    ({"rtol": 0}, ERR, "rtol"),
    ({"rtol": 2}, ERR, "rtol"),
    ({"rtol": math.nan}, ERR, "rtol"),
    ({"max_it": 0}, ERR, "max_it"),
    ({"petsc_options": {"ksp_rtol": 5}}, ERR, "rtol"),
    ({"petsc_options": "ksp_rtol"}, ERR, "petsc_options"),
    ({"material": "steel"}, ERR, "material"),
    ({"voxel_size": -0.0}, ERR, "positive length"),
    ({"voxel_size": "2e-7 m"}, ERR, "voxel size"),
    ({"voxel_size": None, "max_memory": 1}, ERR, "memory"),
    ({"voxel_size": 2e-7, "a_star_cap": 0.5}, ERR, "cap|voxel"),   # found: ignored; fixed
    ({"voxel_size": 2e-7, "diagnose": True}, ERR, "diagnose|voxel"),   # the same
    ({"voxel_size": 2e-7, "max_it": 1}, ERR, "max_it|converge|iteration"),
]

# amfe.homogenize((centers, radii) or Bed(...)): arrays and attributes
_nan = X.copy()
_nan[3, 1] = np.nan
_inf = X.copy()
_inf[0, 0] = np.inf
BED_API = [
    ("centers 2 columns", lambda: Bed(X[:, :2], R), ERR, "centers|shape"),
    ("centers 3-d", lambda: Bed(X[:, :, None], R), ERR, "centers|shape"),
    ("no particles", lambda: Bed(np.zeros((0, 3)), np.zeros(0)), ERR, "particle|empty|no "),
    ("one particle", lambda: Bed(X[:1], R[:1]), ERR, "bond|particle"),
    ("radii too short", lambda: Bed(X, R[:-1]), ERR, "radii|shape"),
    ("radii 2-d", lambda: Bed(X, R[:, None]), ERR, "radii|shape"),
    ("NaN centre", lambda: Bed(_nan, R), ERR, "finite"),
    ("inf centre", lambda: Bed(_inf, R), ERR, "finite"),
    ("zero radius", lambda: Bed(X, np.where(np.arange(27) == 4, 0.0, R)), ERR, "radi"),
    ("negative radius", lambda: Bed(X, -R), ERR, "radi"),
    ("NaN radius", lambda: Bed(X, np.full(27, np.nan)), ERR, "finite|radi"),
    ("complex centres", lambda: Bed(X.astype(complex), R), ERR, "complex|real"),
    ("bool radii", lambda: Bed(X, np.ones(27, bool)), ERR, "real|bool"),
    ("text radii", lambda: Bed(X, np.array(["1e-6"] * 27)), ERR, "real|str"),
    ("object centres", lambda: Bed(X.astype(object), R), ERR, "real|object"),
    ("nested lists", lambda: Bed(X.tolist(), R.tolist()), OK, "same"),
    ("float32", lambda: Bed(X.astype(np.float32), R.astype(np.float32)), OK, "close"),
    ("tuple of arrays", lambda: (X, R), OK, "same"),
    ("translated by 1 mm", lambda: Bed(X + 1e-3, R), OK, "close"),
    ("size attr text", lambda: Bed(X, R, {"size": "abc"}), ERR, "size"),
    ("size attr 2 values", lambda: Bed(X, R, {"size": [1e-5, 1e-5]}), ERR, "size"),
    ("size attr zero", lambda: Bed(X, R, {"size": [0.0, 1e-5, 1e-5]}), ERR, "size"),
    ("size attr NaN", lambda: Bed(X, R, {"size": [np.nan, 1e-5, 1e-5]}), ERR, "size"),
    ("periodic attr text", lambda: Bed(X, R, {"periodic": "yes"}), ERR, "periodic"),
    ("material_E text", lambda: Bed(X, R, {"material_E": "abc"}), ERR, "material_E"),
    ("material_E alone", lambda: Bed(X, R, {"material_E": 70e9}), ERR, "incomplete"),
    ("material_e misspelt", lambda: Bed(X, R, {"material_e": 70e9, "material_nu": 0.3,
                                               "material_psi": 0.08}), ERR, "material_E"),
    ("material_nu 0.6", lambda: Bed(X, R, {"material_E": 70e9, "material_nu": 0.6,
                                           "material_psi": 0.08}), ERR, "nu"),
    ("periodic attr text, bc periodic", lambda: (Bed(X, R, {"periodic": "yes"}), "periodic"),
     ERR, "periodic"),
    ("size attr text, voxel model", lambda: (Bed(X, R, {"size": "abc"}), "voxel"), ERR, "size"),
    ("attrs not a dict", lambda: Bed(X, R, ["size"]), ERR, "attr"),
    ("duplicate particle", lambda: Bed(np.vstack([X, X[:1]]), np.append(R, R[0])), ERR,
     "coincident"),
    ("coordinate 1e300", lambda: Bed(np.where(np.arange(27)[:, None] == 0, 1e300, X), R), ERR,
     "origin|finite|outside"),
    ("radii 1e-300", lambda: Bed(X * 1e-300, R * 1e-300), ERR, "outside|radii"),
    ("radii list of text", lambda: Bed(X, ["a"] * 27), ERR, "real|str"),
    ("size attr ok", lambda: Bed(X, R, {"size": [5.6e-6] * 3}), OK, "finite"),
    ("a string path missing", lambda: "/nonexistent/bed.h5", ERR, "does not exist|cannot"),
    ("a number", lambda: 3, ERR, "bed"),
    ("None", lambda: None, ERR, "bed"),
]

# SolveOptions through amfe.homogenize(bed, **kwargs), frame model
OPTIONS_API = [
    ({"rtol": 0}, ERR, "rtol"), ({"rtol": 1}, ERR, "rtol"), ({"rtol": -1e-6}, ERR, "rtol"),
    ({"rtol": "abc"}, ERR, "rtol"), ({"rtol": True}, ERR, "rtol"),
    ({"rtol": math.inf}, ERR, "rtol"),
    ({"rtol": 1e-8}, OK, "close"),
    ({"solver": "GAMG"}, ERR, "solver"), ({"solver": None}, ERR, "solver"),
    ({"solver": "cholesky"}, OK, "close"), ({"solver": "gamg"}, OK, "close"),
    ({"bc": "bogus"}, ERR, "bc|boundary"), ({"bc": None}, ERR, "bc|boundary"),
    ({"bc": "periodic"}, ERR, "periodic"),
    ({"max_it": 0}, ERR, "max_it"), ({"max_it": -3}, ERR, "max_it"),
    ({"max_it": 1.5}, ERR, "max_it"), ({"max_it": "10"}, ERR, "max_it"),
    ({"petsc_options": {"ksp_rtol": 2}}, ERR, "rtol"),
    ({"petsc_options": {"ksp_max_it": 0}}, ERR, "max_it|ksp_max_it|PETSc"),
    ({"petsc_options": 5}, ERR, "petsc_options"),
    ({"rtol": 1e-6, "petsc_options": {"ksp_rtol": 1e-6}}, ERR, "both set"),
    ({"a_star_cap": 1e-300}, ERR, "a\\* cap"), ({"a_star_cap": 0.9999}, ERR, "a\\* cap"),
    ({"a_star_cap": "x"}, ERR, "a\\* cap|a_star_cap"),
    ({"max_memory": 1}, ERR, "memory"), ({"max_memory": "8G"}, ERR, "max_memory|memory"),
    ({"model": "beam"}, ERR, "model"), ({"model": None}, ERR, "model"),
    ({"voxel_size": 1e-6}, ERR, "voxel"),
    ({"voxel_operator": "matrix-free"}, ERR, "voxel"),
    ({"material": {"E": 70e9}}, ERR, "material"),
    ({"material": {"E": 70e9, "nu": 0.28, "psi": 0.08}}, OK, "E70"),
]

# amfe.Surrogate(path)
SURROGATE_API = [
    ("missing", ERR, "does not exist"), ("dir", ERR, "directory"), ("bed", ERR, "HDF5 file"),
    ("text", ERR, "not a plain amfe checkpoint"), ("empty", ERR, "is empty"),
]
# the same through amfe.Surrogate.load(path), the documented way
SURROGATE_LOAD = [(n, o, w) for n, o, w in SURROGATE_API]

# amfe homogenize BED --model voxel ...: the command line
VOXEL_CLI = [
    (["--voxel-size", "abc"], "voxel-size|length"), (["--voxel-size", "0"], "voxel"),
    (["--voxel-size", "-1e-6"], "voxel"), (["--voxel-size", "nan"], "voxel"),
    (["--voxel-size", "inf"], "voxel"), (["--voxel-size", "1e-320"], "larger --voxel-size"),
    (["--voxel-size", "1e-12"], "memory"), (["--voxel-size", "1e-3mm"], "voxel-size|length|unit"),
    (["--voxel-size", "1 parsec"], "voxel-size|length|unit"),
    (["--voxel-operator", "bogus"], "invalid choice"),
    (["--max-memory", "1K"], "memory"), (["--max-memory", "lots"], "max-memory"),
    (["--bc", "all"], "--bc all"), (["--bc", "subc"], "voxel model solves"),
    (["--bc", "periodic"], "periodic"), (["--solver", "cholesky"], "cholesky|solver"),
    (["--rtol", "0"], "rtol"), (["--rtol", "2"], "rtol"),
    (["-ksp_rtol", "5"], "rtol"), (["--voxel-size", "1"], "necks"),
    (["--cap-a-star", "0.5"], "a\\* cap"), (["--diagnose"], "diagnose"),
    (["-o", "BED"], "input"), (["--vtu", ""], "--vtu"), (["-o", ""], "-o"),
]
FRAME_CLI = [
    (["--voxel-operator", "matrix-free"], "--voxel-operator is an option of --model voxel"),
    (["--model", "beam"], "invalid choice"),
    (["--model", "frame", "--voxel-operator", "assembled"], "--model voxel"),
]

# amfe dataset --from-labels / --export-labels
LABEL_CLI = [
    (["--from-labels", "shard_good"], "needs -o"),
    (["--from-labels", "shard_good", "-o", "OUT", "--seed", "3"], "--seed"),
    (["--from-labels", "shard_good", "-o", "OUT", "--scale", "tiny"], "--scale"),
    (["--from-labels", "shard_good", "-o", "OUT", "--rtol", "1e-6"], "--rtol"),
    (["--from-labels", "shard_good", "-o", "OUT", "--bc", "mixed"], "--bc"),
    (["--from-labels", "missing", "-o", "OUT"], "label table"),
    (["--from-labels", "text", "-o", "OUT"], "label table"),
    (["--from-labels", "empty", "-o", "OUT"], "label table"),
    (["--from-labels", "dir", "-o", "OUT"], "label table"),
    (["--from-labels", "bed", "-o", "OUT"], "label table"),
    (["--from-labels", "shard_good", "-o", "OUT", "--count", "0"], "count"),
    (["--from-labels", "shard_good", "-o", "OUT", "--count", "5"], "count"),
    (["--from-labels", "shard_good", "-o", "OUT", "--count", "-2"], "count"),
    (["--from-labels", "shard_good", "-o", "shard_good"], "input|exists"),
    (["--from-labels", "shard_good", "shard_good", "-o", "OUT"], "more than one shard"),
    (["--export-labels", "missing", "-o", "OUT"], "does not exist"),
    (["--export-labels", "text", "-o", "OUT"], "HDF5|data set"),
    (["--export-labels", "empty", "-o", "OUT"], "HDF5|data set"),
    (["--export-labels", "bed"], "needs -o"),
    (["--export-labels", "bed", "-o", "OUT"], "not a valid data set|data set"),
    (["--export-labels", "shard_good", "-o", "OUT"], "not a valid data set|data set"),
    (["--export-labels", "dir", "-o", "OUT"], "does not exist|directory|data set"),
]
# read_tables(shards): each mutation alone, and with the good shard
SHARD_CASES = [
    (["good"], OK, "4 records"),
    (["format"], ERR, "not an amfe label table"), (["no_format"], ERR, "not an amfe label table"),
    (["seed"], ERR, "record_seed|bed seeds"), (["good", "seed"], ERR, "another data set"),
    (["good", "rtol"], ERR, "another data set"), (["label_rule"], ERR, "label rule|version"),
    (["imaging"], ERR, "imaging|version"), (["index_shift"], ERR, "missing: 0"),
    (["index_dup"], ERR, "missing: 2; held by more than one shard: 1"),
    (["bed_seed"], ERR, "bed seeds"), (["no_index"], ERR, "index|label table"),
    (["good", "good"], ERR, "held by more than one shard: 0, 1, 2, 3"),
]

# amfe predict BEDS... (the tiny model): batch predict
PREDICT_CLI = [
    (["tiny_bed", "tiny_bed"], OK, "batch"),
    (["tiny_bed", "missing"], "failed record", "does not exist"),   # issue 46: its own record
    (["tiny_bed", "dir"], "failed record", "directory"),
    (["tiny_bed", "text"], "failed record", "HDF5|bed file"),
    (["tiny_bed", "empty"], "failed record", "HDF5|bed file|empty"),
    (["tiny_bed", "bed"], "failed record", "size|shape|image|mm"),
    (["tiny_bed", "-o", "tiny_bed"], ERR, "input"),
    (["tiny_bed", "tiny_bed", "-o", "dir"], ERR, "directory"),
    (["tiny_bed", "--threshold", "nan"], ERR, "threshold"),
    (["tiny_bed", "--model", "bed"], ERR, "HDF5 file"),
    (["tiny_bed", "--model", "text"], ERR, "not a plain amfe checkpoint"),
    (["tiny_bed", "--model", "missing"], ERR, "does not exist"),
]


# Cases whose outcome differed from the one written before the run, and why the observed
# one keeps the contract (a clear error, or a right answer); the tests hold the observed.
OBSERVED = {
    "{'petsc_options': {'ksp_max_it': 0}}": (OK, "close", "auto takes Cholesky, which has no "
                                             "iterations: one 'PETSc options never used: "
                                             "-ksp_max_it' warning, the exact constants"),
    "{'max_memory': '8G'}": (OK, "close", "the API takes --max-memory's sizes as text too "
                             "('lots' is refused)"),
    "{'material': {'E': 70000000000.0}}": (OK, "E70", "nu and psi default to steel's, and the "
                                           "result's material.source says so, as --E alone "
                                           "does on the command line"),
    "surrogate path": (ERR, "amfe.Surrogate takes a checkpoint dict", "found here: a "
                       "TypeError traceback ('string indices must be integers'); fixed"),
}
# Tracebacks found here in other helpers' areas (issue 45's faults: Bed attributes, label
# shards' HDF5 reading), recorded as expected failures until fixed there.
XFAIL = {}   # none left: the four tracebacks of this round are fixed (issue 45)


def _mark(case_id, outcome, what):
    """(outcome, what) as observed, and xfail where a traceback is recorded."""
    if case_id in XFAIL:
        pytest.xfail(XFAIL[case_id])
    if case_id in OBSERVED:
        return OBSERVED[case_id][:2]
    return outcome, what


def _ok_constants(res, reference, how):
    """An "ok" outcome: the same constants as the reference (E scaled for 'E70')."""
    ref = np.array([reference.properties[k] for k in sorted(reference.properties)])
    got = np.array([res.properties[k] for k in sorted(res.properties)])
    if how == "E70":
        scale = np.array([70 / 210 if k.startswith(("E", "G")) else 1.0
                          for k in sorted(res.properties)])
        ref = ref * scale
    tol = 0.0 if how == "same" else 1e-5
    assert np.all(np.isfinite(got)), got
    if how == "finite":   # another box: the moduli differ (V), but stay positive
        assert np.all(got[:3] > 0), got
        return
    assert np.allclose(got, ref, rtol=tol, atol=1e-12), (got, ref)   # nu ~ 0 on a lattice


def _expect_error(call, regex):
    with pytest.raises(AmfeError, match=regex):
        call()


# ---------------------------------------------------------------- tests

@pytest.mark.parametrize("kwargs, outcome, what", VOXEL_API,
                         ids=[repr(c[0])[:60] for c in VOXEL_API])
def test_voxel_api(kwargs, outcome, what):
    assert outcome == ERR
    _expect_error(lambda: amfe.homogenize(Bed(X, R), model="voxel", **kwargs), what)


@pytest.mark.parametrize("name, make, outcome, what", BED_API, ids=[c[0] for c in BED_API])
def test_bed_api(name, make, outcome, what, reference):
    outcome, what = _mark(name, outcome, what)

    def call():
        made = make()
        if isinstance(made, tuple) and isinstance(made[1], str):   # (bed, bc or model)
            key = "model" if made[1] == "voxel" else "bc"
            return amfe.homogenize(made[0], **{key: made[1]})
        return amfe.homogenize(made)
    if outcome == ERR:
        _expect_error(call, what)
    else:
        _ok_constants(call(), reference, what)


@pytest.mark.parametrize("kwargs, outcome, what", OPTIONS_API,
                         ids=[repr(c[0])[:60] for c in OPTIONS_API])
def test_options_api(kwargs, outcome, what, reference):
    outcome, what = _mark(repr(kwargs), outcome, what)
    if outcome == ERR:
        _expect_error(lambda: amfe.homogenize(Bed(X, R), **kwargs), what)
    else:
        _ok_constants(amfe.homogenize(Bed(X, R), **kwargs), reference, what)


@pytest.mark.parametrize("name, outcome, what", SURROGATE_API, ids=[c[0] for c in SURROGATE_API])
def test_surrogate_api(name, outcome, what, files):
    outcome, what = _mark("surrogate path", outcome, what)
    _expect_error(lambda: amfe.Surrogate(files[name]), what)


@pytest.mark.parametrize("name, outcome, what", SURROGATE_LOAD,
                         ids=[c[0] for c in SURROGATE_LOAD])
def test_surrogate_load(name, outcome, what, files):
    _expect_error(lambda: amfe.Surrogate.load(files[name]), what)


def _cli(files, args, tmp_path):
    out = str(tmp_path / "out.h5")
    argv = [files.get(a, out if a == "OUT" else a) if a != "BED" else files["bed"] for a in args]
    inputs = {p: sha256(p) for p in files.values() if os.path.isfile(p)}
    code, stdout, err = run_main(argv)
    assert {p: sha256(p) for p in inputs} == inputs, "an input file was changed"
    return code, stdout, err, out


@pytest.mark.parametrize("args, what", VOXEL_CLI, ids=[" ".join(c[0]) for c in VOXEL_CLI])
def test_voxel_cli(args, what, files, tmp_path):
    if " ".join(args) in XFAIL:
        pytest.xfail(XFAIL[" ".join(args)])
    code, out, err, _ = _cli(files, ["homogenize", "BED", "--model", "voxel", *args], tmp_path)
    line = assert_one_error(code, err, "homogenize")
    assert __import__("re").search(what, line), line
    assert os.listdir(tmp_path) == [], os.listdir(tmp_path)


@pytest.mark.parametrize("args, what", FRAME_CLI, ids=[" ".join(c[0]) for c in FRAME_CLI])
def test_frame_cli(args, what, files, tmp_path):
    code, out, err, _ = _cli(files, ["homogenize", "BED", *args], tmp_path)
    assert __import__("re").search(what, assert_one_error(code, err, "homogenize"))


@pytest.mark.parametrize("args, what", LABEL_CLI, ids=[" ".join(c[0]) for c in LABEL_CLI])
def test_label_cli(args, what, files, tmp_path):
    code, out, err, written = _cli(files, ["dataset", *args], tmp_path)
    assert __import__("re").search(what, assert_one_error(code, err, "dataset"))
    assert not os.path.exists(written)


@pytest.mark.parametrize("names, outcome, what", SHARD_CASES,
                         ids=["+".join(c[0]) for c in SHARD_CASES])
def test_label_shards(names, outcome, what, files):
    from amfe.dataset.labels import read_tables
    outcome, what = _mark("+".join(names), outcome, what)
    paths = [files[f"shard_{n}"] for n in names]
    if outcome == ERR:
        _expect_error(lambda: read_tables(paths), what)
    else:
        table = read_tables(paths)
        assert table["index"].tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("args, outcome, what", PREDICT_CLI,
                         ids=[" ".join(c[0]) for c in PREDICT_CLI])
def test_predict_cli(args, outcome, what, files, tmp_path):
    argv = ["predict", *args] + ([] if "--model" in args else ["--model", "model"])
    outcome, what = _mark(" ".join(args), outcome, what)
    code, out, err, _ = _cli(files, argv + ["--threads", "1"], tmp_path)
    if outcome == "failed record":   # a batch: the other bed predicted, exit 3
        assert code == 3 and "Traceback" not in err, err
        assert re.search(what, out) and "FAILED (not predicted)" in out, out
        return
    if outcome == "flagged":
        assert code == 0 and "Traceback" not in err, err
        assert out.count(what) == 1 and "in distribution" in out, out   # the other bed's
        return
    if outcome == ERR:
        assert __import__("re").search(what, assert_one_error(code, err, "predict"))
        return
    assert code == 0, err
    import json
    sur = amfe.Surrogate.load(files["model"])
    single = sur.predict([files["tiny_bed"]])
    both = sur.predict([files["tiny_bed"], files["tiny_bed"]])
    assert both["mean"].shape[0] == 2
    assert np.allclose(both["mean"], single["mean"][0], rtol=1e-6)
    printed = out   # the CLI's own table: finite numbers, one block per bed
    assert printed.count(files["tiny_bed"]) >= 2 and "nan" not in printed.lower(), printed
    json.dumps  # (the JSON of a batch is checked in tests/test_predict_batch.py)

"""Fuzz `amfe predict`, `pack` and `homogenize` with bad beds, attributes and options (issue 18).

hypothesis draws small HDF5 beds (a real tiny bed, then a mutation: bad
shapes, dtypes, values, missing datasets, junk attributes) and option values
(good ones and bad ones: nan, inf, negative, text, bad output paths), and
runs the command in this process through amfe.cli.main. Every run must end
in one of two ways:

- exit 0 with a finite result (the JSON parses strictly, every constant finite;
  pack: the bed reads back), or
- exit 2 with one error line (after the subcommand's usage for a bad option),
  no traceback, and no file written.

The input files are never changed (hashed before and after). Each command
gets a bounded number of examples (derandomized: the same cases every run).

PENDING lists the cases that waited for the solve-side fixes of issue 18
(each with its item); they are drawn like the others now that those fixes
are in (AMFE_FUZZ_ALL=0 leaves them out, to compare).
AMFE_FUZZ_LOG=FILE appends one line per run (case, options, exit code, last
stderr line) to FILE, to see what was drawn.
"""
import json
import math
import os
import tempfile

import h5py
import numpy as np
import pytest
from cli_fixtures import assert_one_error, mutated_checkpoint, run_main, sha256, tiny_model
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ALL = os.environ.get("AMFE_FUZZ_ALL", "1") == "1"
FUZZ = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))


def _pending(group, values):
    return list(values) + (PENDING[group] if ALL else [])


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(model, bed, nan model): the tiny surrogate, a bed it predicts, and its NaN copy."""
    d = tmp_path_factory.mktemp("fuzz")
    model, bed = tiny_model(str(d))

    def nan(ck):
        ck["members"][1] = {k: v * float("nan") for k, v in ck["members"][1].items()}
    return str(model), str(bed), str(mutated_checkpoint(model, d / "nan.pt", nan))


# ---------------------------------------------------------------- bad beds

BAD = [float("nan"), float("inf"), -float("inf"), 0.0, -1e-5, 5e-324]
HUGE = [1e300, -1e300]
MUTATIONS = ["none", "subset", "value", "radius", "radius_huge", "shape_centers",
             "shape_radii", "dtype", "missing", "group", "empty", "not_hdf5", "attr_size",
             "attr_seed", "attr_layer_thickness", "material_full"]
# handled by predict now, by homogenize after rel-solve
PREDICT_MUTATIONS = ["value_huge", "scale_1e-300", "scale_1e300", "material_text",
                     "material_partial"]

# Cases the solve side of issue 18 fixed, drawn by default (AMFE_FUZZ_ALL=0 leaves them out):
# coordinates at 1e-300 / 1e300 and material attributes of the wrong type
# or incomplete (items 3, 12) in homogenize (predict handles them: drawn for it); a bed
# declaring 2e9 particles (11: refused from the dataset shapes before reading); absurd pack sizes
# and radii, seeds >= 2^64 (10, 11); homogenize -o
# checked before the solve (6, 7). Pack's: PACK_PENDING.
PENDING = {
    "homogenize_bed": PREDICT_MUTATIONS,
    "bed": ["huge_count"],
    "homogenize_output": ["OVER_INPUT", "DIR", "/proc/x.json", "FILE/x.json"],
}


@st.composite
def bed_files(draw, base, kinds):
    """(name, writer(path)) of a bed: ``base`` (centers, radii, attrs) and one of ``kinds``."""
    centers, radii, attrs = (np.array(base[0]), np.array(base[1]), dict(base[2]))
    kind = draw(st.sampled_from(kinds))
    n = len(radii)
    layout = {"particles/centers": centers, "particles/radii": radii}
    if kind == "subset":
        keep = np.sort(draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True)))
        layout = {"particles/centers": centers[keep], "particles/radii": radii[keep]}
    elif kind in ("value", "value_huge"):
        centers[draw(st.integers(0, n - 1)), draw(st.integers(0, 2))] = draw(
            st.sampled_from(BAD if kind == "value" else HUGE))
    elif kind == "radius":
        radii[draw(st.integers(0, n - 1))] = draw(st.sampled_from(BAD + [-1.0]))
    elif kind == "radius_huge":
        radii[draw(st.integers(0, n - 1))] = draw(st.sampled_from([1e-3, 1.0, 1e300]))
    elif kind == "shape_centers":
        layout["particles/centers"] = draw(st.sampled_from(
            [centers[:, :2], np.hstack([centers, centers[:, :1]]), centers[:, 0],
             centers[..., None], centers[:-1]]))
    elif kind == "shape_radii":
        layout["particles/radii"] = draw(st.sampled_from([radii[:-1], radii[:, None],
                                                          np.append(radii, 1e-5), radii[0]]))
    elif kind == "dtype":
        name = draw(st.sampled_from(sorted(layout)))
        layout[name] = draw(st.sampled_from([layout[name].astype(np.float32),
                                             layout[name].astype(np.int64),
                                             layout[name].astype(np.complex128),
                                             layout[name].astype("S8"),
                                             layout[name] > 0]))
    elif kind == "missing":
        del layout[draw(st.sampled_from(sorted(layout)))]
    elif kind == "group":
        layout[draw(st.sampled_from(sorted(layout)))] = None   # a group where a dataset belongs
    elif kind == "empty":
        layout = {"particles/centers": np.zeros((0, 3)), "particles/radii": np.zeros(0)}
    elif kind.startswith("attr_"):
        attrs[kind[5:]] = draw(st.sampled_from(
            ["abc", -1.0, 0.0, float("nan"), [1.0, 1.0, 1.0], [1e-4, 1e-4], [-1e-4, 1e-4, 1e-4],
             [float("nan")] * 3, 2 ** 62]))
    elif kind == "material_full":   # a complete, valid material other than steel
        attrs.update(material_E=70e9, material_nu=0.33, material_psi=0.08,
                     material_density=2700.0)
    elif kind == "material_text":
        attrs.update(material_E="abc", material_nu=0.3, material_psi=0.5, material_density=1.0)
    elif kind == "material_partial":   # E without nu, psi, density
        attrs = {k: v for k, v in attrs.items() if not k.startswith("material_")}
        attrs["material_E"] = 70e9
    elif kind.startswith("scale_"):
        layout["particles/centers"] = centers * float(kind[6:])

    def write(path):
        if kind == "not_hdf5":
            with open(path, "wb") as fh:
                fh.write(b"\x89HDF\r\n junk " * 3)
            return
        with h5py.File(path, "w") as f:
            if kind == "huge_count":   # 2e9 particles declared, none stored
                f.create_dataset("particles/centers", shape=(2 * 10 ** 9, 3), dtype="f8")
                f.create_dataset("particles/radii", shape=(2 * 10 ** 9,), dtype="f8")
            for name, data in layout.items():
                if data is None:
                    f.create_group(name)
                elif kind != "huge_count":
                    f[name] = data
            for k, v in attrs.items():
                f.attrs[k] = v
    return kind, write


def _base(bed_path):
    with h5py.File(bed_path, "r") as f:
        return (f["particles/centers"][()], f["particles/radii"][()],
                {k: v for k, v in f.attrs.items()})


# ---------------------------------------------------------------- the two allowed endings

def _strict_json(text):
    def refuse(token):
        raise AssertionError(f"JSON holds {token}")
    return json.loads(text, parse_constant=refuse)


def _finite(values):
    return all(v is not None and math.isfinite(v) for v in values)


def check_run(command, argv, directory, inputs, output=None, result=None, case=""):
    """Run ``amfe COMMAND ARGV`` in-process and check the ending (see the module docstring).

    result(stdout, output) -> None checks a success (exit 0).
    """
    before = {p: sha256(p) for p in inputs if os.path.isfile(p)}
    listing = sorted(os.listdir(directory))
    code, out, err = run_main([command, *argv])
    if os.environ.get("AMFE_FUZZ_LOG"):
        with open(os.environ["AMFE_FUZZ_LOG"], "a") as fh:
            fh.write(f"{command} {case} {argv[1:]} -> {code}: "
                     f"{(err.strip().splitlines() or [''])[-1]}\n")
    assert "Traceback" not in err, err
    if code == 0:
        result(out, output)
    else:
        assert_one_error(code, err, command)
        assert sorted(os.listdir(directory)) == listing, "a failed run left a file"
    assert {p: sha256(p) for p in before} == before, "an input file changed"
    return code


def _predict_ok(out, output):
    text = out if output == "-" else open(output).read() if output else None
    if text is not None:
        res = _strict_json(text)["beds"][0]   # always {"beds": [...]} (issue 46)
        assert _finite(res["properties"].values()) and res["source"] in ("surrogate", "solver")
    assert "nan" not in out.lower().replace("nan.pt", "")


# ---------------------------------------------------------------- predict

OUTPUTS = ["OUT", "-", None, "OVER_INPUT", "OVER_MODEL", "DIR", "/proc/x.json", "FILE/x.json"]


def _workdir(d, data, base, kinds=None):
    """Write the bed (mutated by one of ``kinds``, if given) and the DIR and FILE decoys."""
    kind, write = (data.draw(bed_files(base, kinds), label="bed") if kinds
                   else ("none", _copy_writer(base)))
    path = os.path.join(d, "bed.h5")
    write(path)
    os.mkdir(os.path.join(d, "DIR"))
    open(os.path.join(d, "FILE"), "w").close()
    return kind, path


def _copy_writer(base):
    def write(path):
        with h5py.File(path, "w") as f:
            f["particles/centers"], f["particles/radii"] = base[0], base[1]
            f.attrs.update(base[2])
    return write


def _output(name, d, bed, model=None):
    return {"OUT": os.path.join(d, "out.json"), "OVER_INPUT": bed, "OVER_MODEL": model,
            "DIR": os.path.join(d, "DIR"), "FILE/x.json": os.path.join(d, "FILE", "x.json")
            }.get(name, name)


def _options(data, choices):
    argv = []
    for flag, values in choices:
        value = data.draw(st.one_of(st.none(), st.sampled_from(values)), label=flag)
        if value is not None:
            argv.append(f"{flag}={value}")
    return argv


def fuzz_run(command, data, base, kinds, extra, outputs, ok, inputs=(), model=None):
    """One example: ``amfe COMMAND BED EXTRA(dir) -o OUTPUT``, checked by check_run.

    The bed is ``base`` mutated by one of ``kinds`` (None: the good bed); the
    output is drawn from ``outputs`` (see _output; None: no -o).
    """
    with tempfile.TemporaryDirectory() as d:
        kind, path = _workdir(d, data, base, kinds)
        argv = [path, *extra(d)]
        output = _output(data.draw(st.sampled_from(outputs), label="-o"), d, path, model)
        argv += ["-o", output] if output else []
        check_run(command, argv, d, [path, *inputs], output, ok, kind if kinds else "options")


@FUZZ
@given(data=st.data())
def test_fuzz_predict_beds(tiny, data):
    """Bad beds, good options: a prediction or one line."""
    model, bed, _ = tiny
    fuzz_run("predict", data, _base(bed), _pending("bed", MUTATIONS + PREDICT_MUTATIONS),
             lambda d: ["--model", model], ["OUT", "-", None], _predict_ok, [model])


@FUZZ
@given(data=st.data())
def test_fuzz_predict_options(tiny, data):
    """The good bed, bad options, models and output paths: a prediction or one line."""
    model, bed, nan_model = tiny

    def extra(d):
        use = data.draw(st.sampled_from([model, nan_model, d, os.path.join(d, "none.pt"),
                                         os.path.join(d, "FILE")]), label="--model")
        fallback = ["--fallback"] if data.draw(st.booleans(), label="--fallback") else []
        return ["--model", use, *fallback] + _options(data, (
            ("--threshold", ["0.5", "0", "1e9", "nan", "inf", "-1", "x"]),
            ("--threads", ["1", "0", "-1", "2.5", "99999"])))
    fuzz_run("predict", data, _base(bed), None, extra, OUTPUTS, _predict_ok,
             [model, nan_model], model)


# ---------------------------------------------------------------- pack

def _pack_ok(out, output):
    from amfe.io.bedfile import read_bed
    bed = read_bed(output)
    assert len(bed.radii) > 0 and np.isfinite(bed.centers).all()


PACK_VALUES = {
    "--size": [["0.12", "0.12", "0.08"], ["0.15", "0.1", "0.1"], ["0", "0.1", "0.1"],
               ["-0.1", "0.1", "0.1"], ["nan", "0.1", "0.1"], ["inf", "0.1", "0.1"],
               ["0.1", "x", "0.1"]],
    "--seed": ["0", "7", "-1", "x", "1.5"],
    "--mean-radius": ["12", "14", "0", "-3", "nan"],
    "--enlargement": [["1.05", "1.1"], ["1.1", "1.05"], ["0", "1"], ["nan", "1.1"]],
    "--jitter": ["0", "0.03", "-1", "nan", "5"],
    "--a-star-max": ["0.9", "0.98", "0.9934", "1.5", "-1", "nan"],
    "--layer-thickness": ["0.05", "0.1", "0", "-1", "inf"],
    "--track-width": ["0.05", "0", "-1", "nan"],
    "--hatch-spacing": ["0.06", "0.01", "0", "nan"],
    "--skip-fraction": ["0", "0.3", "1", "-0.5"],
    "--scale": ["tiny", "small"],
}
# PENDING["pack"]: allocations of 887 GiB and tens of GB, particles of 10 nm, seed 2^64.
PACK_PENDING = {"--size": [["100", "100", "100"], ["1e300", "1", "1"], ["10", "10", "3"]],
                "--mean-radius": ["0.01"], "--seed": ["18446744073709551616"]}


@FUZZ
@given(data=st.data())
def test_fuzz_pack(data):
    with tempfile.TemporaryDirectory() as d:
        os.mkdir(os.path.join(d, "DIR"))
        open(os.path.join(d, "FILE"), "w").close()
        argv = []
        for flag in sorted(PACK_VALUES):
            if data.draw(st.integers(0, 3), label=f"{flag}?") == 0:   # each option: 1 in 4
                values = PACK_VALUES[flag] + (PACK_PENDING.get(flag, []) if ALL else [])
                value = data.draw(st.sampled_from(values), label=flag)
                argv += [flag, *value] if isinstance(value, list) else [f"{flag}={value}"]
        if "--size" not in argv and "--scale" not in argv:
            argv += ["--size", "0.12", "0.12", "0.08"]   # keep the default-size runs short
        output = data.draw(st.sampled_from(["OUT", "OUT", "DIR", "/proc/b.h5", "FILE/b.h5"]),
                           label="-o")
        output = {"OUT": os.path.join(d, "b.h5"), "DIR": os.path.join(d, "DIR"),
                  "FILE/b.h5": os.path.join(d, "FILE", "b.h5")}.get(output, output)
        check_run("pack", [*argv, "-o", output], d, [], output, _pack_ok)


# ---------------------------------------------------------------- homogenize

def _homogenize_ok(out, output):
    res = _strict_json(open(output).read())
    assert _finite(res["properties"].values())


@FUZZ
@given(data=st.data())
def test_fuzz_homogenize_beds(tiny, data):
    """Bad beds, good options: finite constants or one line."""
    kinds = _pending("bed", _pending("homogenize_bed", MUTATIONS))
    fuzz_run("homogenize", data, _base(tiny[1]), kinds, lambda d: ["--quiet"], ["OUT"],
             _homogenize_ok)


@FUZZ
@given(data=st.data())
def test_fuzz_homogenize_options(tiny, data):
    """The good bed, bad options and output paths: finite constants or one line."""
    def extra(d):
        return ["--quiet"] + _options(data, (
            ("--rtol", ["1e-6", "1e-10", "0", "1", "10", "nan", "-1", "x"]),
            ("--cap-a-star", ["0.9", "0.98", "1.5", "nan", "-1"]),
            ("--bc", ["kubc", "mixed", "periodic"])))
    fuzz_run("homogenize", data, _base(tiny[1]), None, extra,
             _pending("homogenize_output", ["OUT"]), _homogenize_ok)


# ---------------------------------------------------------------- issue 31: attribute names

MATERIAL_FILE = {"material_E": 70e9, "material_nu": 0.33, "material_psi": 0.08,
                 "material_density": 2700.0}
NAME_VARIANTS = {   # how a user might spell an attribute (the identity is the right spelling)
    "same": lambda k: k, "lower": str.lower, "upper": str.upper, "title": str.title,
    "swapcase": str.swapcase, "dash": lambda k: k.replace("_", "-"),
    "no_separator": lambda k: k.replace("_", ""), "space": lambda k: k.replace("_", " "),
    "no_prefix": lambda k: k[len("material_"):], "Material": lambda k: "M" + k[1:],
}


@FUZZ
@given(data=st.data())
def test_fuzz_material_attribute_names(tiny, data):
    """The file's material with one attribute spelt a drawn way: the file's material (spelt
    right) or one line naming the attribute and its spelling, never a solve as steel."""
    key = data.draw(st.sampled_from(sorted(MATERIAL_FILE)), label="attribute")
    variant = data.draw(st.sampled_from(sorted(NAME_VARIANTS)), label="variant")
    name = NAME_VARIANTS[variant](key)
    if name.lower() == "density":   # a bare 'density' is no material name amfe would take
        name = key
    centers, radii, attrs = _base(tiny[1])
    attrs = {k: v for k, v in attrs.items() if not k.startswith("material_")}
    attrs.update({k: v for k, v in MATERIAL_FILE.items() if k != key}, **{name: MATERIAL_FILE[key]})

    def ok(out, output):
        material = _strict_json(open(output).read())["material"]
        assert name == key and material["source"] == "bed file", material
        assert [material[k] for k in ("E", "nu", "psi")] == [70e9, 0.33, 0.08]

    with tempfile.TemporaryDirectory() as d:
        _kind, path = _workdir(d, data, (centers, radii, attrs))
        out = os.path.join(d, "out.json")
        code = check_run("homogenize", [path, "--quiet", "-o", out], d, [path], out, ok, variant)
        assert (code == 0) == (name == key), (name, code)


# ---------------------------------------------------------------- issue 31: option conflicts

@FUZZ
@given(data=st.data())
def test_fuzz_option_conflicts(tiny, data):
    """--rtol with -ksp_rtol (command line) or rtol / max_it with their PETSc options (API):
    one given is honoured and recorded; both are one error naming both."""
    import amfe
    from amfe.solvers.petsc import init_petsc
    rtol = data.draw(st.sampled_from([None, 1e-6, 1e-9]), label="rtol")
    ksp_rtol = data.draw(st.sampled_from([None, "0.5", "1e-6", "1e-10"]), label="-ksp_rtol")
    solver = data.draw(st.sampled_from(["auto", "gamg"]), label="solver")
    conflict = rtol is not None and ksp_rtol is not None
    if data.draw(st.booleans(), label="api"):
        max_it = data.draw(st.sampled_from([None, 500]), label="max_it")
        ksp_max_it = data.draw(st.sampled_from([None, "400"]), label="-ksp_max_it")
        options = {k: v for k, v in (("ksp_rtol", ksp_rtol), ("-ksp_max_it", ksp_max_it)) if v}
        conflict = conflict or (max_it is not None and ksp_max_it is not None)
        try:
            r = amfe.homogenize(tiny[1], rtol=rtol, max_it=max_it, solver=solver,
                                petsc_options=options)
        except amfe.AmfeError as exc:
            # issue 45: rtol 0.5 may stop CG at its initial guess, which is refused
            assert (conflict and "give only one of them" in str(exc)) or (
                ksp_rtol == "0.5" and "after 0 iterations" in str(exc)), exc
            return
        assert not conflict
        if r.solver["method"] == "gamg":
            assert r.solver["rtol"] == float(ksp_rtol or rtol or r.solver["rtol"])
        return
    opts = init_petsc().Options()
    before = set(opts.getAll())
    argv = [*(["--rtol", str(rtol)] if rtol else []),
            *(["-ksp_rtol", ksp_rtol] if ksp_rtol else [])]

    def ok(out, output):
        s = _strict_json(open(output).read())["solver"]
        if s["method"] == "gamg" and (rtol or ksp_rtol):
            assert s["rtol"] == float(rtol or ksp_rtol), s
    try:
        with tempfile.TemporaryDirectory() as d:
            out = os.path.join(d, "out.json")
            code = check_run("homogenize", [tiny[1], "--quiet", "--solver", solver, *argv, "-o",
                                            out], d, [tiny[1]], out, ok, "conflict")
    finally:   # the command line's PETSc options stay in the database: take them out again
        for name in set(opts.getAll()) - before:
            opts.delValue(name)
    # issue 45: -ksp_rtol 0.5 is looser than amfe homogenize accepts (1e-4)
    assert (code == 2) == (conflict or ksp_rtol == "0.5"), (argv, code)


# ---------------------------------------------------------------- issue 31: training data faults

TRAIN_DATA_FAULTS = {   # name: (data set array, index into the ok row's entry, value)
    "nan_pixel": ("images", (0, 1, 1), np.nan), "inf_pixel": ("images", (0, 0, 3), np.inf),
    "negative_pixel": ("images", (0, 2, 2), -0.5), "pixel_2": ("images", (0, 4, 4), 2.0),
    "nan_label": ("labels", (0,), np.nan), "inf_label": ("labels", (4,), -np.inf),
    "label_1e300": ("labels", (1,), 1e300), "label_1e-300": ("labels", (2,), 1e-300),
    "zero_modulus": ("labels", (0,), 0.0), "negative_modulus": ("labels", (2,), -1e11),
    "nu_1e6": ("labels", (5,), 1e6), "nu_-40": ("labels", (3,), -40.0),
}


@FUZZ
@given(data=st.data())
def test_fuzz_training_data_faults(data):
    """A tiny data set with none or one drawn fault in a drawn ok record, and training options
    (a learning rate that diverges, no validation, --max-train 0): a model with finite
    metrics only for good data and options, else one line and no file."""
    from cli_fixtures import tiny_dataset

    from amfe.training.checkpoint import load_checkpoint
    fault = data.draw(st.sampled_from(["none"] + sorted(TRAIN_DATA_FAULTS)), label="fault")
    row = data.draw(st.sampled_from([0, 10, 21, 39]), label="row")   # ok rows of tiny_dataset
    lr = data.draw(st.sampled_from(["1e-3", "1e6"]), label="--lr")
    # (--max-train 5 is not drawn: a fault in a record it leaves out is never read, and the run
    # rightly succeeds; which records it keeps depends on the split)
    extra = _options(data, (("--val-fraction", ["0.2", "0"]), ("--max-train", ["0"])))

    def ok(out, output):
        metrics = load_checkpoint(output)["metrics"].get("validation", {})
        assert _finite(m["mre"] for k, m in metrics.items() if isinstance(m, dict))
    with tempfile.TemporaryDirectory() as d:
        path = tiny_dataset(os.path.join(d, "d.h5"))
        if fault != "none":
            name, index, value = TRAIN_DATA_FAULTS[fault]
            with h5py.File(path, "r+") as f:
                arr = f[name][()].astype(np.float64 if name == "labels" else np.float32)
                arr[(row, *index)] = value
                del f[name]
                f[name] = arr
        model = os.path.join(d, "m.pt")
        code = check_run("train", [path, "-o", model, "--epochs", "1", "--batch-size", "8",
                                   "--quiet", "--lr", lr, *extra], d, [path], model, ok, fault)
    good = fault == "none" and lr == "1e-3" and "--max-train=0" not in extra
    assert (code == 0) == good, (fault, lr, extra, code)

"""Issue 31 faults of the inputs and of training: misspelt material attributes, an rtol given
twice, `amfe train` on bad data or diverging, a translated bed, Result.to_json on a bad path
and Surrogate.predict on a list of beds. Each test runs the issue's input and asserts the fix."""
import os

import h5py
import numpy as np
import pytest
from cli_fixtures import assert_one_error, run_main, tiny_dataset, tiny_model

import amfe
from amfe.errors import AmfeError
from amfe.io.bedfile import read_bed, write_bed
from amfe.model.bed import Bed
from amfe.model.frame import build_frame, frame_origin

NAMES = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy")


@pytest.fixture
def petsc_db():
    """Take out again the PETSc options an in-process command line adds to the database."""
    from amfe.solvers.petsc import init_petsc
    opts = init_petsc().Options()
    before = set(opts.getAll())
    yield
    for name in set(opts.getAll()) - before:
        opts.delValue(name)


def constants(result):
    return np.array([result.properties[n] for n in NAMES])


# ------------------------------------------------- material attributes spelt otherwise

STEEL_LIKE = {"material_E": 70e9, "material_nu": 0.33, "material_psi": 0.08}


@pytest.mark.parametrize("attrs, rename", [
    ({"material_e": 70e9, "material_Nu": 0.33, "material_PSI": 0.08},
     "'material_Nu' to 'material_nu', 'material_PSI' to 'material_psi', 'material_e' to "
     "'material_E'"),
    ({**STEEL_LIKE, "material_Density": 2700.0}, "'material_Density' to 'material_density'"),
    ({"material_E": 70e9, "material_Nu": 0.33, "material_psi": 0.08}, "'material_Nu' to "
                                                                      "'material_nu'"),
    ({"Material-PSI": 0.5}, "'Material-PSI' to 'material_psi'"),
    ({"E": 70e9}, "'E' to 'material_E'"),
])
def test_misspelt_material_attribute_is_refused_naming_the_spelling(tmp_path, bed, attrs, rename):
    """The issue: material_e, material_Nu, material_PSI were ignored and the bed solved as steel."""
    path = tmp_path / "bed.h5"
    write_bed(path, Bed(bed.centers, bed.radii, attrs))
    with pytest.raises(AmfeError, match="spelt exactly material_E, material_nu, material_psi, "
                                        "material_density \\(the case matters\\)") as exc:
        read_bed(path)
    assert str(exc.value).endswith("rename " + rename)
    with pytest.raises(AmfeError, match="rename " + rename):     # an in-memory Bed too
        amfe.homogenize(Bed(bed.centers, bed.radii, attrs))
    code, out, err = run_main(["homogenize", path, "-o", tmp_path / "r.json", "--quiet"])
    assert assert_one_error(code, err, "homogenize").endswith("rename " + rename)
    assert not (tmp_path / "r.json").exists()


def test_unknown_numeric_material_attribute_is_refused_text_passes(bed):
    with pytest.raises(AmfeError, match="'material_G' is not a material constant amfe reads"):
        amfe.homogenize(Bed(bed.centers, bed.radii, {"material_G": 80e9}))
    ok = Bed(bed.centers, bed.radii, {**STEEL_LIKE, "material_name": "AlSi10Mg"})
    assert ok.material().E == 70e9   # a text label is no number that could be meant


# ------------------------------------------------- one number from two options

def test_rtol_and_ksp_rtol_together_are_refused(tmp_path, bed, bed_path, petsc_db):
    """The issue: -ksp_rtol 0.5 silently overrode --rtol 1e-6 (the JSON said 0.5, Ex 3 % off)."""
    out = tmp_path / "r.json"
    code, _, err = run_main(["homogenize", bed_path, "--rtol", "1e-6", "-ksp_rtol", "0.5",
                             "-o", out, "--quiet"])
    line = assert_one_error(code, err, "homogenize")
    assert "rtol 1e-06 (--rtol" in line and "-ksp_rtol 0.5" in line and "give only one" in line
    assert not out.exists()
    for options in ({"ksp_rtol": 0.5}, {"-ksp_rtol": "0.5"}):
        with pytest.raises(AmfeError, match="rtol 1e-06 .* and -ksp_rtol 0.5 both set"):
            amfe.homogenize(bed, rtol=1e-6, petsc_options=options)
    with pytest.raises(AmfeError, match="max_it 5 .* and -ksp_max_it 3 both set"):
        amfe.homogenize(bed, max_it=5, petsc_options={"ksp_max_it": 3})


def test_ksp_rtol_alone_is_honoured_and_recorded(bed):
    r = amfe.homogenize(bed, solver="gamg", petsc_options={"ksp_rtol": 1e-6})
    assert r.solver["rtol"] == 1e-6 and r.solver["residual_limit"] == pytest.approx(1e-5)


def test_dataset_refuses_ksp_rtol_it_would_not_record(tmp_path, petsc_db):
    out = tmp_path / "d.h5"
    code, _, err = run_main(["dataset", "-o", out, "--count", "2", "--scale", "tiny",
                             "-ksp_rtol", "1e-6"])
    assert "give the tolerance as --rtol" in assert_one_error(code, err, "dataset")
    assert os.listdir(tmp_path) == []


# ------------------------------------------------- a bed far from the origin

def test_translated_bed_gives_the_same_constants(bed):
    """The frame is built about the bed's middle: moving the stored bed changes nothing.

    The reference is the translated bed moved back exactly (c + T - T is exact), so the
    two hold the same stored geometry; before the fix they differed by ~1e-7 at 1e4 m.
    """
    for shift in ([1e4, 0, 0], [-3e3, 2e3, 5e3]):
        moved = bed.centers + np.array(shift)
        back = moved - np.array(shift)
        a = amfe.homogenize((moved, bed.radii), solver="cholesky")
        b = amfe.homogenize((back, bed.radii), solver="cholesky")
        assert np.max(np.abs(constants(a) / constants(b) - 1)) < 1e-12


def test_frame_origin_subtracts_exactly_and_is_zero_near_zero(bed):
    assert np.all(frame_origin(bed.centers) == 0)    # generated beds: the numbers of before
    moved = bed.centers + np.array([1e4, -7e3, 0.0])
    origin = frame_origin(moved)
    assert origin[0] > 9e3 and origin[1] < -6e3 and origin[2] == 0
    assert np.array_equal((moved - origin) + origin, moved)
    frame = build_frame(moved, bed.radii)
    assert np.allclose(frame.centers * frame.length_scale + frame.origin, moved[frame.kept],
                       rtol=0, atol=1e-15 * 1e4)


def test_the_issues_translation_is_refused_with_what_the_rounding_costs(bed):
    """1e7 m is 8e11 mean radii: float64 stores the positions to 1.5e-4 R there, which moved
    the Poisson ratios by 2e-4 even with exact arithmetic; the limit is now 1e9 R."""
    with pytest.raises(AmfeError, match="more than 1e\\+09 mean radii from the origin, beyond "
                                        "which float64 stores positions to worse than 2e-7"):
        amfe.homogenize((bed.centers + 1e7, bed.radii))


# ------------------------------------------------- amfe train: bad data, divergence

def _mutated(path, change):
    with h5py.File(path, "r+") as f:
        change(f)
    return path


TRAIN_FAULTS = {
    "label_1e300": (lambda f: _set(f, "labels", (10, 0), 1e300), "more than 1000 times from"),
    "nan_pixel": (lambda f: _set(f, "images", (5, 0, 2, 2), np.nan), "non-finite pixels"),
    "inf_pixel": (lambda f: _set(f, "images", (5, 0, 2, 2), np.inf), "non-finite pixels"),
    "fill_above_1": (lambda f: _set(f, "images", (5, 0, 2, 2), 3.0), "outside [0, 1]"),
    "nan_label_ok": (lambda f: _set(f, "labels", (12, 4), np.nan), "ok records at rows 12 have "
                                                                   "non-finite labels"),
    "negative_modulus": (lambda f: _set(f, "labels", (12, 1), -1e9), "non-positive moduli"),
    "poisson_50": (lambda f: _set(f, "labels", (12, 5), 50.0), "nu_xy 50, no compliance"),
}


def _set(f, name, index, value):
    data = f[name][()]
    if name == "labels":   # amfe dataset stores float64 labels (the synthetic set float32)
        data = data.astype(np.float64)
    data[index] = value
    del f[name]
    f[name] = data


def _train(tmp_path, data, *extra):
    model = tmp_path / "m.pt"
    code, out, err = run_main(["train", data, "-o", model, "--epochs", "1", "--batch-size", "8",
                               "--quiet", *extra])
    return code, err, model


@pytest.mark.parametrize("fault", sorted(TRAIN_FAULTS))
def test_train_refuses_bad_data_before_training(tmp_path, fault):
    change, message = TRAIN_FAULTS[fault]
    data = _mutated(tiny_dataset(str(tmp_path / "d.h5")), change)
    code, err, model = _train(tmp_path, data)
    assert message in assert_one_error(code, err, "train")
    assert not model.exists() and not model.with_suffix(".png").exists()


def test_train_refuses_a_bad_test_set_before_training(tmp_path):
    data = tiny_dataset(str(tmp_path / "d.h5"))
    test = _mutated(tiny_dataset(str(tmp_path / "t.h5")), TRAIN_FAULTS["nan_pixel"][0])
    code, err, model = _train(tmp_path, data, "--test", test)
    assert "t.h5: records at rows 5 have non-finite pixels" in assert_one_error(code, err, "train")
    assert not model.exists()


@pytest.mark.parametrize("extra", [["--lr", "1e6"], ["--lr", "1e6", "--val-fraction", "0"],
                                   ["--lr", "3", "--epochs", "3"]])
def test_diverged_training_exits_non_zero_and_writes_nothing(tmp_path, extra):
    """The issue: --lr 1e6 exited 0 with a checkpoint predicting non-finite constants."""
    data = tiny_dataset(str(tmp_path / "d.h5"))
    code, err, model = _train(tmp_path, data, *extra)
    assert "training diverged" in assert_one_error(code, err, "train")
    assert not model.exists() and not model.with_suffix(".png").exists()


def test_a_trained_model_records_its_error_against_the_mean(tmp_path):
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.guards import DIVERGED_FACTOR
    data = tiny_dataset(str(tmp_path / "d.h5"))
    code, err, model = _train(tmp_path, data, "--epochs", "3")
    assert code == 0, err
    ratios = load_checkpoint(model)["metrics"]["validation"]["error_vs_mean"]
    assert len(ratios) == 6 and all(0 < r < DIVERGED_FACTOR for r in ratios)


def test_check_fit_against_the_mean_by_hand():
    """Predicting the training mean scores 1; twice its error per label is the limit."""
    from amfe.training.data import Normalizer
    from amfe.training.guards import check_fit
    rng = np.random.default_rng(0)
    labels = np.column_stack([rng.uniform(1e10, 1e11, (50, 3)), rng.uniform(0.1, 0.3, (50, 3))])
    norm = Normalizer.fit(labels)
    mean = norm.decode(np.zeros((50, 6))).numpy()
    assert np.allclose(check_fit(mean, labels, norm, 1e-3), 1.0)
    assert np.allclose(check_fit(labels, labels, norm, 1e-3), 0.0, atol=1e-12)
    off = mean.copy()
    off[:, 5] = labels[:, 5] + 2 * (mean[:, 5] - labels[:, 5])   # error x 4 on nu_xy
    with pytest.raises(AmfeError, match="nu_xy is 4 times that of predicting the training mean"):
        check_fit(off, labels, norm, 1e-3)
    # two validation beds at the training mean: any model is "worse than the mean" there,
    # but an error of half a training standard deviation is no divergence (a warning)
    near, warned = mean[:2], []
    model = norm.decode(norm.encode(near).double() + 0.5).numpy()
    ratios = check_fit(model, near, norm, 1e-3, warned.append)
    assert min(ratios) > 1e3 and len(warned) == 1 and "not learned" in warned[0]
    with pytest.raises(AmfeError, match="predictions of 1 validation beds are not finite"):
        check_fit(np.where(np.arange(50)[:, None] == 3, np.nan, mean), labels, norm, 1e-3)


def test_max_train_zero_is_an_error(tmp_path):
    """The issue: --max-train 0 was taken as 'all' without a word."""
    code, err, model = _train(tmp_path, tiny_dataset(str(tmp_path / "d.h5")), "--max-train", "0")
    assert "--max-train: must be a whole number >= 1, got 0" in assert_one_error(code, err,
                                                                                  "train")


# ------------------------------------------------- API: Result.to_json, Surrogate.predict

@pytest.fixture(scope="module")
def result(bed):
    return amfe.homogenize(bed, solver="cholesky")


@pytest.mark.parametrize("where, message", [
    (lambda d: d, "is a directory; give a file name"),
    (lambda d: d / "FILE" / "r.json", "cannot write"),
    (lambda d: "/proc/r.json", "cannot write /proc/r.json"),
    (lambda d: "", "must be a file name"),
])
def test_to_json_on_a_bad_path_is_one_amfe_error(tmp_path, result, where, message):
    (tmp_path / "FILE").write_text("x")
    listing = sorted(os.listdir(tmp_path))
    with pytest.raises(AmfeError, match=message):
        result.to_json(where(tmp_path))
    assert sorted(os.listdir(tmp_path)) == listing


def test_to_json_writes_a_good_path(tmp_path, result):
    result.to_json(tmp_path / "r.json")
    import json
    assert json.loads((tmp_path / "r.json").read_text())["properties"]["Ex"] == result.Ex


def test_predict_takes_a_list_of_beds_as_a_batch(tmp_path):
    from amfe.training.predict import Surrogate
    model, bed_file = tiny_model(str(tmp_path))
    sur = Surrogate.load(model)
    one = sur.predict(bed_file)
    both = sur.predict([read_bed(bed_file), bed_file])
    assert both["mean"].shape == (2, 6)
    assert np.allclose(both["mean"], one["mean"][0], rtol=1e-6, atol=0)
    with pytest.raises(AmfeError, match="a list mixing beds with other things"):
        sur.predict([bed_file, 3])
    with pytest.raises(AmfeError, match="images must be an array of numbers"):
        sur.predict([["a"]])

"""Split conformal intervals: nominal coverage on synthetic data, none at an uncalibrated size."""
import math

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.training.conformal import calibrate, calibration, interval_block, intervals, size_key

NAMES = ("Ex", "Ey", "nu_xy")


def synthetic(rng, n, spread_informative):
    """Predictions, labels and spreads: relative errors ~ spread * t(4) (heavy-tailed)."""
    pred = rng.uniform(1e9, 3e9, size=(n, 3))
    pred[:, 2] = rng.uniform(0.1, 0.4, size=n)
    spread = rng.uniform(0.005, 0.05, size=(n, 3))
    sigma = spread if spread_informative else np.full((n, 3), 0.03)
    labels = pred * (1 + sigma * rng.standard_t(4, size=(n, 3)))
    return pred, labels, spread


def binomial_band(p, n, z=3.5):
    return z * math.sqrt(p * (1 - p) / n)


@pytest.mark.parametrize("use_spread", [False, True])
def test_intervals_cover_at_the_nominal_rate(use_spread):
    rng = np.random.default_rng(7)
    n_cal, n_test, coverage = 400, 4000, 0.9
    p, y, s = synthetic(rng, n_cal, use_spread)
    cal = calibrate(p, y, NAMES, s if use_spread else None, coverage)
    p, y, s = synthetic(rng, n_test, use_spread)
    lo, hi = intervals(p, NAMES, cal, s if use_spread else None)
    covered = ((lo <= y) & (y <= hi)).mean(axis=0)
    # Marginal guarantee: E[coverage] in [0.9, 0.9 + 1/(n+1)]; the calibration draw adds the
    # quantile's own spread (beta with variance ~ a(1-a)/n_cal) to the test sample's.
    tol = binomial_band(coverage, n_test) + binomial_band(coverage, n_cal)
    assert np.all(covered > coverage - tol), covered
    assert np.all(covered < coverage + 1 / (n_cal + 1) + tol), covered


def test_too_narrow_a_quantile_fails_the_coverage_check():
    """The test can fail: the 70 % quantile called 90 % covers about 70 %."""
    rng = np.random.default_rng(8)
    p, y, _ = synthetic(rng, 400, False)
    cal = calibrate(p, y, NAMES, None, 0.7)
    p, y, _ = synthetic(rng, 4000, False)
    lo, hi = intervals(p, NAMES, cal)
    covered = ((lo <= y) & (y <= hi)).mean(axis=0)
    assert np.all(covered < 0.9 - binomial_band(0.9, 4000) - binomial_band(0.9, 400))


def test_quantile_is_the_conformal_rank():
    pred = np.ones((9, 1))
    labels = pred * (1 + np.arange(1, 10)[:, None] / 100)    # relative residuals 0.01 .. 0.09
    cal = calibrate(pred, labels, ("Ex",), coverage=0.8)      # ceil(10 * 0.8) = 8th smallest
    assert cal["quantile"]["Ex"] == pytest.approx(0.08)
    assert math.isinf(calibrate(pred, labels, ("Ex",), coverage=0.95)["quantile"]["Ex"])
    with pytest.raises(AmfeError):
        calibrate(pred, labels[:5], ("Ex",))


def test_no_interval_without_calibration_at_the_size():
    rng = np.random.default_rng(9)
    p, y, _ = synthetic(rng, 200, False)
    conf = calibration({size_key((0.6e-3, 0.6e-3)): calibrate(p, y, NAMES)}, 0.9, NAMES)
    assert size_key((0.6e-3, 0.6e-3, 0.3e-3)) == "0.6x0.6"
    small = interval_block(p[0], NAMES, conf, (0.6e-3, 0.6e-3, 0.3e-3))
    assert small["coverage"] == 0.9 and small["calibration"]["n"] == 200
    lo, hi = small["intervals"]["Ex"]
    assert lo < p[0, 0] < hi
    big = interval_block(p[0], NAMES, conf, (3e-3, 3e-3, 0.3e-3))
    assert big["intervals"] is None and big["coverage"] is None
    assert "3x3" in big["calibration"]["note"] and not big["interval_flag"]
    assert interval_block(p[0], NAMES, None, (0.6e-3, 0.6e-3))["intervals"] is None


def test_wide_intervals_flag_the_bed():
    pred = np.full((50, 1), 1e9)
    labels = pred * (1 + np.linspace(-0.3, 0.3, 50)[:, None])
    conf = calibration({"0.6x0.6": calibrate(pred, labels, ("Ex",))}, 0.9, ("Ex",))
    assert interval_block([1e9], ("Ex",), conf, (0.6e-3, 0.6e-3))["interval_flag"]
    conf["flag_half_width"] = 0.5
    assert not interval_block([1e9], ("Ex",), conf, (0.6e-3, 0.6e-3))["interval_flag"]


def test_calibrate_script_stores_the_sizes_calibration(tmp_path):
    """run/train/calibrate_intervals.py on a held-out tiny data set: the checkpoint's quantiles are
    calibrate()'s on the model's own predictions, and predict then gives intervals."""

    from cli_fixtures import tiny_dataset, tiny_model

    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.data import dataset_info, read_rows
    from amfe.training.predict import Surrogate
    from amfe.vocab import LABEL_NAMES

    model, bed = tiny_model(str(tmp_path))
    held = tiny_dataset(str(tmp_path / "held.h5"), n=30, failed=())
    from run.train import calibrate_intervals as script
    assert script.main([str(model), str(held), "-o", str(model)]) == 2   # never in place
    out = tmp_path / "cal.pt"
    assert script.main([str(model), str(held), "-o", str(out), "--coverage", "0.8"]) == 0
    conf = load_checkpoint(out)["conformal"]
    assert conf["coverage"] == 0.8 and list(conf["sizes"]) == ["0.15x0.15"]
    sur = Surrogate.load(model)
    images, labels = read_rows(held, dataset_info(held)["ok"], sur.inputs)
    res = sur.predict(images)
    want = calibrate(res["mean"], labels, LABEL_NAMES, res["spread"], 0.8)
    have = conf["sizes"]["0.15x0.15"]
    assert have["n"] == want["n"] == 30 and have["uses_spread"]
    for key in ("quantile", "spread_scale"):
        assert have[key] == pytest.approx(want[key], rel=1e-6)
    got = interval_block(res["mean"][0], LABEL_NAMES, conf, (0.15e-3, 0.15e-3), res["spread"][0])
    assert got["coverage"] == 0.8 and got["calibration"]["n"] == 30


def test_two_data_sets_of_one_size_calibrate_together(tmp_path):
    """Held-out sets of the same bed size are pooled (not the last one kept): the quantiles
    are calibrate()'s on both sets' predictions together, n their sum."""

    from cli_fixtures import TINY_ATTRS, tiny_model
    from test_training import write_synthetic

    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.data import dataset_info, read_rows
    from amfe.training.predict import Surrogate
    from amfe.vocab import LABEL_NAMES

    model, bed = tiny_model(str(tmp_path))
    a = write_synthetic(str(tmp_path / "a.h5"), n=20, shape=(1, 5, 5), attrs=TINY_ATTRS,
                        failed=(), seed=1)
    b = write_synthetic(str(tmp_path / "b.h5"), n=15, shape=(1, 5, 5), attrs=TINY_ATTRS,
                        failed=(), seed=2)
    from run.train import calibrate_intervals as script
    out = tmp_path / "cal.pt"
    assert script.main([str(model), str(a), str(b), "-o", str(out)]) == 0
    have = load_checkpoint(out)["conformal"]["sizes"]["0.15x0.15"]
    sur = Surrogate.load(model)
    preds, labels, spreads = [], [], []
    for path in (a, b):
        images, y = read_rows(path, dataset_info(path)["ok"], sur.inputs)
        res = sur.predict(images)
        preds.append(res["mean"]), labels.append(y), spreads.append(res["spread"])
    want = calibrate(np.concatenate(preds), np.concatenate(labels), LABEL_NAMES,
                     np.concatenate(spreads), 0.9)
    assert have["n"] == want["n"] == 35
    assert have["quantile"] == pytest.approx(want["quantile"], rel=1e-6)

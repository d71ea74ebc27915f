"""The flag's operating point (issue 46): `amfe predict --flag-share`, amfe.predict's
flag_share and `amfe sweep --flag-share` move the 0.6 mm model's risk threshold to the one
that the given share of its calibration beds exceed, and nothing else."""
import csv
import json

import numpy as np
import pytest
from cli_fixtures import run_main

import amfe
from amfe.errors import AmfeError
from amfe.training.flagrisk import RISK_TABLE, fit, load_flag, risk, threshold_for
from amfe.training.shipped import models_dir
from amfe.vocab import LABEL_NAMES

TIMED = ("seconds", "timings")


def _untimed(record):
    return {k: v for k, v in record.items() if k not in TIMED}


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _synthetic(n=2000, seed=0):
    """Features, (pred, labels, spread, skipped) of n made-up beds whose error grows with the
    first feature: something the risk can learn."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 4))
    labels = np.exp(rng.normal(size=(n, 6)) * 0.1) + 1.0
    noise = rng.normal(size=(n, 6)) * 0.05 * np.exp(X[:, :1])
    return X, (labels * (1 + noise), labels, np.full((n, 6), 0.02), X[:, 1] > 0)


def test_a_share_flags_that_share_of_the_calibration_beds():
    X, data = _synthetic()
    model = fit(X, data, bond_scale=1.0, flag_share=0.19)
    score = risk(model, X)
    # the table is the calibration risk's percentiles, and the file's own share is its threshold
    assert np.allclose(model["risk_quantiles"], np.quantile(score, RISK_TABLE), rtol=0, atol=0)
    assert threshold_for(model, 0.19) == pytest.approx(model["threshold"], rel=1e-12, abs=1e-12)
    assert threshold_for(model) == model["threshold"]
    for share in (0.05, 0.19, 0.3, 0.37, 0.5, 0.9):
        flagged = score > threshold_for(model, share)
        assert abs(flagged.mean() - share) <= 1.5 / len(X), share
    shares = np.linspace(0.01, 0.99, 50)
    assert np.all(np.diff([threshold_for(model, s) for s in shares]) <= 0)   # more, lower


@pytest.mark.parametrize("bad", [0, 1, 1.5, -0.2, float("nan"), True, "0.3", None])
def test_a_share_outside_0_1_is_refused(bad):
    model = load_flag(models_dir() / "flag_small.json")
    if bad is None:   # None means the file's own share
        assert threshold_for(model, bad) == model["threshold"]
        return
    with pytest.raises(AmfeError, match="between 0 and 1"):
        threshold_for(model, bad)


def test_a_flag_file_without_its_table_is_refused_clearly():
    model = load_flag(models_dir() / "flag_small.json")
    del model["risk_quantiles"]
    assert threshold_for(model) == model["threshold"]
    with pytest.raises(AmfeError, match="recalibrate"):
        threshold_for(model, 0.3)


def test_the_shipped_flag_file_keeps_its_threshold_in_its_table():
    model = load_flag(models_dir() / "flag_small.json")
    table = model["risk_quantiles"]
    assert len(table) == len(RISK_TABLE) and np.all(np.diff(table) >= 0)
    assert threshold_for(model, model["flag_share"]) == pytest.approx(model["threshold"],
                                                                      rel=1e-12)


@pytest.fixture(scope="module")
def small_bed(tmp_path_factory):
    d = tmp_path_factory.mktemp("share")
    code, _, err = run_main(["pack", "--scale", "small", "--seed", "5", "-o", d / "bed.h5"])
    assert code == 0, err
    return d / "bed.h5", d


def test_the_share_moves_the_flag_and_nothing_else(small_bed):
    bed, d = small_bed
    base = amfe.predict(str(bed)).to_dict()
    r, model = base["risk"], load_flag(models_dir() / "flag_small.json")
    assert r["flag_share"] == model["flag_share"] and r["threshold"] == model["threshold"]
    # the constants: the model's ensemble corrected by the factors the risk block records
    from amfe.training.predict import Surrogate
    raw = Surrogate.load(models_dir() / "multiscale_small.pt").predict(str(bed))["mean"][0]
    assert [base["properties"][k] for k in LABEL_NAMES] == pytest.approx(
        [v * r["correction"][k] for v, k in zip(raw, LABEL_NAMES)], rel=1e-9)
    # the intervals: its risk bin's quantiles times the scale the risk block records
    cal = model["bins"][r["bin"]]
    for k, (lo, hi) in base["intervals"].items():
        p = base["properties"][k]
        half = cal["quantile"][k] * abs(p) * (r["interval_scale"][k] + cal["spread_scale"][k])
        assert (lo, hi) == pytest.approx((p - half, p + half), rel=1e-9)
    # shares whose thresholds lie on either side of this bed's risk
    table = np.array(model["risk_quantiles"])
    below = 1.0 - RISK_TABLE[np.flatnonzero(table < r["risk"] - 1e-9).max()]
    above = 1.0 - RISK_TABLE[np.flatnonzero(table > r["risk"] + 1e-9).min()]
    flagged, clear = amfe.predict(str(bed), flag_share=below), \
        amfe.predict(str(bed), flag_share=above)
    assert flagged.flagged and "risk" in flagged.flag_reasons
    assert not clear.flagged and "risk" not in clear.flag_reasons
    for p, share in ((flagged, below), (clear, above)):
        got = p.to_dict()
        assert got["risk"]["flag_share"] == pytest.approx(share)
        assert got["risk"]["risk"] == r["risk"] and got["risk"]["bin"] == r["bin"]
        assert got["properties"] == base["properties"] and got["intervals"] == base["intervals"]
    # the command line gives the same record as Python
    code, out, err = run_main(["predict", bed, "--flag-share", repr(below), "-o", d / "p.json"])
    assert code == 0, err
    cli = json.loads((d / "p.json").read_text())["beds"][0]
    assert json.dumps(_untimed(cli), sort_keys=True) == \
        json.dumps(_untimed(flagged.to_dict()), sort_keys=True)
    assert f"{100 * below:.3g} % of the calibration beds exceed" in out
    # an unflagged bed is "not flagged", never "in distribution": the risk claims no more
    code, out, err = run_main(["predict", bed, "--flag-share", repr(above)])
    assert code == 0, err
    assert "not flagged: its risk is below" in out and "in distribution" not in out


def test_a_bad_share_stops_before_any_work(small_bed):
    bed, d = small_bed
    code, _, err = run_main(["predict", bed, "--flag-share", "1.2", "-o", d / "x.json"])
    assert code == 2 and "between 0 and 1" in err and not (d / "x.json").exists()
    with pytest.raises(AmfeError, match="between 0 and 1"):
        amfe.predict(str(bed), flag_share=0)


def test_a_bed_flagged_otherwise_says_the_share_is_not_used(tmp_path):
    code, _, err = run_main(["pack", "--size", "0.9", "0.9", "0.3", "--seed", "2",
                             "-o", tmp_path / "b.h5"])
    assert code == 0, err
    got = amfe.predict(str(tmp_path / "b.h5"), flag_share=0.3).to_dict()
    assert "risk" not in got
    assert any(n.startswith("flag share 0.3 not used") for n in got["notes"]), got["notes"]


def test_the_sweep_flags_as_predict_does(tmp_path):
    grid = ["--grid", "hatch_spacing=0.1", "--grid", "track_width=0.05,0.1", "--seeds", "1",
            "--no-progress", "--method", "surrogate"]
    code, _, err = run_main(["sweep", "-o", tmp_path / "s", *grid, "--flag-share", "0.6"])
    assert code == 0, err
    spec = json.loads((tmp_path / "s" / "sweep.json").read_text())
    assert spec["flag_share"] == 0.6
    from amfe.study.run import bed_of
    from amfe.study.spec import SweepSpec
    sweep = SweepSpec(**{**spec, "points": tuple(spec["points"]), "seeds": tuple(spec["seeds"]),
                         "size": tuple(spec["size"])})
    for k, row in enumerate(_rows(tmp_path / "s" / "beds.csv")):
        mine = amfe.predict(bed_of(sweep, k)[0], flag_share=0.6)
        assert row["flagged"] == str(mine.flagged).lower()
    # another share is another sweep: its rows would be flagged otherwise
    code, _, err = run_main(["sweep", "-o", tmp_path / "s", *grid, "--flag-share", "0.2"])
    assert code != 0 and "holds another sweep" in err
    with pytest.raises(AmfeError, match="needs --method surrogate"):
        SweepSpec(points=({"track_width": 1e-4},), seeds=(0,), flag_share=0.3)


def test_a_batch_reads_the_error_network_once_and_gives_each_bed_its_own_flag(small_bed):
    bed, d = small_bed
    code, _, err = run_main(["pack", "--scale", "small", "--seed", "6", "-o", d / "bed6.h5"])
    assert code == 0, err
    alone = [amfe.predict(str(p)).to_dict() for p in (bed, d / "bed6.h5")]
    batch = [p.to_dict() for p in amfe.predict([str(bed), str(d / "bed6.h5")])]
    assert alone[0]["risk"]["risk"] != pytest.approx(alone[1]["risk"]["risk"], rel=1e-3)
    for one, many in zip(alone, batch):   # float32 passes of another batch: to rounding
        assert many["risk"]["risk"] == pytest.approx(one["risk"]["risk"], rel=1e-5)
        assert many["risk"]["bin"] == one["risk"]["bin"]
        for block in ("correction", "interval_scale"):
            assert many["risk"][block] == pytest.approx(one["risk"][block], rel=1e-5)
        assert many["properties"] == pytest.approx(one["properties"], rel=1e-5)
        assert many["timings"]["flag"] > 0

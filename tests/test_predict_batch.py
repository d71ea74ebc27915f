"""`amfe predict BED [BED ...]`: one process, one batch, the same numbers as one bed at a time."""
import json

import numpy as np
import pytest
from cli_fixtures import run_main, tiny_model

from amfe.io.result_meta import validate


@pytest.fixture(scope="module")
def model_and_beds(tmp_path_factory):
    from amfe.io.bedfile import read_bed, write_bed
    from amfe.model.bed import Bed
    d = tmp_path_factory.mktemp("batch")
    model, bed = tiny_model(str(d))
    base = read_bed(bed)
    beds = [bed]
    # Two more beds: the first one's particles shifted and shrunk (different images).
    for k, (shift, shrink) in enumerate([(10e-6, 0.97), (-15e-6, 0.93)]):
        base = Bed(base.centers + [shift, 0.0, 0.0], base.radii * shrink, base.attrs)
        path = d / f"bed{k}.h5"
        write_bed(path, base)
        beds.append(path)
    return model, beds, d


def test_batch_equals_one_at_a_time(model_and_beds):
    model, beds, d = model_and_beds
    code, _, err = run_main(["predict", *beds, "--model", model, "-o", d / "all.json"])
    assert code == 0, err
    batch = json.loads((d / "all.json").read_text())
    validate(batch)
    assert [b["input"]["path"] for b in batch["beds"]] == [str(b) for b in beds]
    assert all(b["bc"] == "kubc" for b in batch["beds"])
    singles = []
    for k, bed in enumerate(beds):
        code, _, err = run_main(["predict", bed, "--model", model, "-o", d / f"one{k}.json"])
        assert code == 0, err
        one = json.loads((d / f"one{k}.json").read_text())
        validate(one)
        assert "beds" not in one and one["bc"] == "kubc"
        singles.append(one)
    for one, got in zip(singles, batch["beds"]):
        for name, value in one["properties"].items():
            assert got["properties"][name] == pytest.approx(value, rel=1e-6), name
        assert got["spread_score"] == pytest.approx(one["spread_score"], rel=1e-6, abs=1e-12)
    # The beds differ, so equality is not a constant output.
    ex = [one["properties"]["Ex"] for one in singles]
    assert np.ptp(ex) > 1e-6 * abs(ex[0])


def test_batch_schema_refuses_a_bed_without_its_path(model_and_beds):
    from amfe.errors import AmfeError
    model, beds, d = model_and_beds
    code, _, err = run_main(["predict", *beds[:2], "--model", model, "-o", d / "two.json"])
    assert code == 0, err
    batch = json.loads((d / "two.json").read_text())
    del batch["beds"][1]["input"]
    with pytest.raises(AmfeError):
        validate(batch)


def _with_conformal(src, dst, sizes, q=0.05, flag_half_width=0.1):
    from cli_fixtures import mutated_checkpoint

    from amfe.training.conformal import calibration
    from amfe.vocab import LABEL_NAMES

    def change(ckpt):
        cal = {"n": 99, "quantile": {k: q for k in LABEL_NAMES},
               "spread_scale": {k: 1.0 for k in LABEL_NAMES}, "uses_spread": False}
        ckpt["conformal"] = calibration({s: cal for s in sizes}, 0.9, LABEL_NAMES,
                                        flag_half_width)
    return mutated_checkpoint(src, dst, change)


def test_predict_gives_intervals_at_a_calibrated_size(model_and_beds):
    model, beds, d = model_and_beds
    calibrated = _with_conformal(model, d / "conf.pt", ["0.15x0.15"])
    code, out, err = run_main(["predict", beds[0], "--model", calibrated, "-o", d / "c.json"])
    assert code == 0, err
    got = json.loads((d / "c.json").read_text())
    validate(got)
    assert got["coverage"] == 0.9 and got["interval_calibration"]["n"] == 99
    for name, value in got["properties"].items():
        lo, hi = got["intervals"][name]
        assert lo == pytest.approx(value - 0.05 * abs(value), rel=1e-12)
        assert hi == pytest.approx(value + 0.05 * abs(value), rel=1e-12)
    assert "nominal coverage 90 %" in out and not got["predict"]["flags"]["interval"]
    # A half-width limit under 5 % flags every bed through its intervals.
    strict = _with_conformal(model, d / "strict.pt", ["0.15x0.15"], flag_half_width=0.01)
    code, out, err = run_main(["predict", beds[0], "--model", strict, "-o", d / "s.json"])
    got = json.loads((d / "s.json").read_text())
    assert code == 0 and got["flagged"] and "interval" in got["flag_reasons"]
    validate(got)


def test_predict_claims_no_interval_at_an_uncalibrated_size(model_and_beds):
    model, beds, d = model_and_beds
    other = _with_conformal(model, d / "other.pt", ["0.6x0.6"])
    code, out, err = run_main(["predict", beds[0], "--model", other, "-o", d / "u.json"])
    assert code == 0, err
    got = json.loads((d / "u.json").read_text())
    validate(got)
    assert got["intervals"] is None and got["coverage"] is None
    assert "no calibration beds of size 0.15x0.15 mm" in got["interval_calibration"]["note"]
    assert "no interval claimed" in out


def test_stiffness_and_model_together_are_refused(model_and_beds):
    model, beds, d = model_and_beds
    code, _, err = run_main(["predict", beds[0], "--model", model, "--stiffness"])
    assert code != 0 and "give --model or --stiffness, not both" in err
    assert "Traceback" not in err

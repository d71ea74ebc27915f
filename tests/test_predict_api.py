"""amfe.predict and `amfe predict -o`: the same records; a batch with a bed that cannot be
predicted; the E scaling (issue 46)."""
import json

import numpy as np
import pytest
import torch
from cli_fixtures import run_main, tiny_model

import amfe
from amfe.io.result_meta import validate

TIMED = ("seconds", "timings")   # wall-clock times differ from run to run


@pytest.fixture(scope="module")
def model_and_beds(tmp_path_factory):
    from amfe.io.bedfile import read_bed, write_bed
    from amfe.model.bed import Bed
    d = tmp_path_factory.mktemp("api")
    model, bed = tiny_model(str(d))
    base = read_bed(bed)
    # a bed of twice the size: its image is not the tiny model's shape (not predictable)
    big = d / "big.h5"
    write_bed(big, Bed(base.centers, base.radii, {**base.attrs,
                                                   "size": [2 * s for s in base.attrs["size"]]}))
    return model, [bed, big], d, base


def _untimed(record):
    return {k: v for k, v in record.items() if k not in TIMED}


def test_cli_json_equals_python_and_a_failed_bed_has_its_own_record(model_and_beds):
    model, beds, d, _ = model_and_beds
    code, out, err = run_main(["predict", *beds, "--model", model, "-o", d / "b.json"])
    assert code == 3, err   # some bed failed: its record says why, the others are predicted
    got = json.loads((d / "b.json").read_text())
    validate(got)
    assert list(got) == ["schema_version", "command", "beds"] and len(got["beds"]) == 2
    ok, bad = got["beds"]
    assert ok["source"] == "surrogate" and ok["error"] is None
    assert bad["source"] == "failed" and bad["properties"] is None and bad["flagged"]
    assert "shape" in bad["error"] or "image" in bad["error"], bad["error"]
    assert "FAILED (not predicted)" in out
    py = amfe.predict([str(b) for b in beds], model=model)
    assert [p.source for p in py] == ["surrogate", "failed"]
    for cli, mine in zip(got["beds"], py):   # bit for bit on the numbers
        assert json.dumps(_untimed(cli), sort_keys=True) == \
            json.dumps(_untimed(mine.to_dict()), sort_keys=True)
    one = amfe.predict(beds[0], model=model)
    assert isinstance(one, amfe.Prediction) and one.properties == ok["properties"]
    assert "Ex=" in repr(one) and "failed" in repr(py[1])
    one.to_json(d / "one.json")
    assert json.loads((d / "one.json").read_text())["properties"] == ok["properties"]


def test_one_unpredictable_bed_is_still_an_error(model_and_beds):
    model, beds, d, _ = model_and_beds
    code, _, err = run_main(["predict", beds[1], "--model", model, "-o", d / "x.json"])
    assert code == 2 and "error:" in err and not (d / "x.json").exists()


def test_fallback_solves_the_bed_that_cannot_be_predicted(model_and_beds):
    model, beds, d, _ = model_and_beds
    code, _, err = run_main(["predict", *beds, "--model", model, "--fallback",
                             "--threshold", "1e9", "-o", d / "f.json"])
    assert code == 0, err
    got = json.loads((d / "f.json").read_text())
    validate(got)
    solved = got["beds"][1]
    assert solved["source"] == "solver" and solved["error"]
    direct = amfe.homogenize(beds[1])
    assert solved["properties"]["Ex"] == pytest.approx(direct.Ex, rel=1e-6)


def test_the_moduli_scale_exactly_with_E(model_and_beds):
    """Every spring is E x f(a*, R, nu, psi): two solves of one bed at two E."""
    _, _, _, bed = model_and_beds
    steel = amfe.homogenize(bed, material={"E": 210e9, "nu": 0.28, "psi": 0.08}, rtol=1e-12)
    ti = amfe.homogenize(bed, material={"E": 114e9, "nu": 0.28, "psi": 0.08}, rtol=1e-12)
    for name in ("Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy"):
        assert getattr(ti, name) / getattr(steel, name) == pytest.approx(114 / 210, rel=1e-12)
    for name in ("nu_yz", "nu_xz", "nu_xy"):
        assert getattr(ti, name) == pytest.approx(getattr(steel, name), rel=1e-12)


def test_the_surrogate_scales_a_bed_that_differs_only_in_E(model_and_beds):
    from amfe.model.bed import Bed
    model, _, d, bed = model_and_beds
    ckpt = torch.load(model, weights_only=True)
    ckpt["material"] = {"E": 210e9, "nu": 0.28, "psi": 0.08}
    torch.save(ckpt, d / "steel.pt")
    attrs = {k: v for k, v in bed.attrs.items() if not k.startswith("material_")}
    steel = Bed(bed.centers, bed.radii, {**attrs, "material_E": 210e9, "material_nu": 0.28,
                                         "material_psi": 0.08})
    ti = Bed(bed.centers, bed.radii, {**attrs, "material_E": 114e9, "material_nu": 0.28,
                                      "material_psi": 0.08})
    a, b = amfe.predict([steel, ti], model=d / "steel.pt")
    assert a.source == b.source == "surrogate" and not a.notes
    for name, value in a.properties.items():
        want = value * 114e9 / 210e9 if name.startswith("E") else value
        assert b.properties[name] == pytest.approx(want, rel=1e-12), name
    assert "E_bed / E_model = 0.542857" in b.notes[0]
    other_nu = Bed(bed.centers, bed.radii, {**attrs, "material_E": 210e9, "material_nu": 0.33,
                                            "material_psi": 0.08})
    c = amfe.predict(other_nu, model=d / "steel.pt")
    assert c.source == "failed" and "nu and psi inputs are coming" in c.error


def test_the_default_surrogate_names_amfe_predict_for_another_size():
    from amfe.errors import AmfeError
    from amfe.model.bed import Bed
    sur = amfe.Surrogate.load()
    bed = Bed(np.array([[0.3e-3, 0.3e-3, 0.15e-3]]), np.array([20e-6]),
              {"size": [1.2e-3, 1.2e-3, 0.3e-3]})
    with pytest.raises(AmfeError, match=r"use amfe\.predict\(bed\)"):
        sur.predict(bed)

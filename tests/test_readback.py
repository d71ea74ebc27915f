"""amfe.read_result reads back every JSON amfe writes, and writing it again gives the same bytes."""
import json
import os
import shutil

import pytest
from cli_fixtures import run_main, tiny_model
from helpers import ROOT

import amfe
from amfe.errors import AmfeError
from amfe.io.readback import Predictions, ResultSet, read_result
from amfe.io.result import Result

GOLDEN = os.path.join(ROOT, "tests", "data")


def round_trip(path, tmp_path):
    """(object read, whether writing it again gave the file's bytes)."""
    obj = read_result(path)
    again = tmp_path / "again.json"
    obj.to_json(again)
    with open(path, "rb") as a, open(again, "rb") as b:
        return obj, a.read() == b.read()


@pytest.mark.parametrize("name", ["kubc_2ranks", "mixed_gamg"])
def test_a_homogenize_result_round_trips(name, tmp_path):
    obj, same = round_trip(os.path.join(GOLDEN, f"golden_result_{name}.json"), tmp_path)
    assert isinstance(obj, Result) and same
    with open(os.path.join(GOLDEN, f"golden_result_{name}.json")) as f:
        d = json.load(f)
    assert obj.Ex == d["properties"]["Ex"] and obj.C.tolist() == d["C"]
    assert Result.from_json(os.path.join(GOLDEN, f"golden_result_{name}.json")).bc == d["bc"]


def test_a_bounds_report_round_trips_as_a_result_set(tmp_path):
    path = os.path.join(GOLDEN, "golden_result_all_periodic.json")
    obj, same = round_trip(path, tmp_path)
    assert isinstance(obj, ResultSet) and same
    assert list(obj) == ["kubc", "subc", "periodic"]
    with open(path) as f:
        d = json.load(f)
    assert obj["subc"].Ey == d["conditions"]["subc"]["properties"]["Ey"]
    assert "energy gap" in repr(obj)
    with pytest.raises(AmfeError, match="read it with amfe.read_result"):
        Result.from_json(path)


def test_a_voxel_result_round_trips(tmp_path):
    bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)
    result = amfe.homogenize(bed, model="voxel")   # voxels of R / 4
    result.to_json(tmp_path / "voxel.json")
    obj, same = round_trip(tmp_path / "voxel.json", tmp_path)
    assert same and obj.extra["model"] == result.extra["model"]
    assert obj.C.tolist() == result.C.tolist()


@pytest.fixture(scope="module")
def predictions(tmp_path_factory):
    d = tmp_path_factory.mktemp("predict")
    model, bed = tiny_model(str(d))
    other = d / "other.h5"
    shutil.copy(bed, other)
    for name, beds in (("one.json", [bed]), ("two.json", [bed, other])):
        code, out, err = run_main(["predict", *beds, "--model", model, "-o", d / name])
        assert code == 0, err
    return d


@pytest.mark.parametrize("name,count", [("one.json", 1), ("two.json", 2)])
def test_predictions_round_trip(predictions, name, count, tmp_path):
    obj, same = round_trip(predictions / name, tmp_path)
    assert isinstance(obj, Predictions) and same and len(obj) == count


@pytest.mark.parametrize("text,match", [("{", "as JSON"), ("[1, 2]", "not a result"),
                                        ('{"schema_version": 4}', "not a complete")])
def test_what_is_not_a_result_is_one_error(tmp_path, text, match):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    with pytest.raises(AmfeError, match=match):
        read_result(bad)
    with pytest.raises(AmfeError, match="does not exist"):
        read_result(tmp_path / "missing.json")


def test_a_bed_prints_what_it_is_not_its_arrays():
    bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)
    text = repr(bed)
    assert text.startswith(f"Bed({bed.n} particles")
    assert "0.1 x 0.1 x 0.06 mm (recorded size)" in text
    assert "[" not in text and len(text) < 200
    loose = repr(amfe.Bed(bed.centers, bed.radii))
    assert "spheres' bounding box" in loose


def test_a_surrogate_prints_what_it_reads_and_where_it_holds():
    text = repr(amfe.Surrogate.load())
    assert text.startswith("Surrogate(multiscale_small.pt: ")
    assert "0.6 x 0.6 x 0.3 mm" in text and "90 % intervals at 0.6x0.6 mm" in text
    assert text.endswith("; runs in numpy)")

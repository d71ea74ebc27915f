"""JSON results say what they are: the header of amfe.io.result_meta and the shipped JSON Schema."""
import copy
import hashlib
import json

import h5py
import numpy as np
import pytest
from helpers import run_cli

import amfe
from amfe.errors import AmfeError
from amfe.io.result_meta import HEADER_KEYS, SCHEMA_VERSION, load_schema, validate
from amfe.model.bonds import find_pairs
from amfe.model.material import Material

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is a test extra: "
                                 "pip install -e .[test]")


@pytest.fixture(scope="module")
def bed_path(tmp_path_factory):
    """A bed with a floating bonded pair far away: 2 particles and 1 bond are not kept."""
    bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=4)
    r = bed.radii.mean()
    far = bed.centers.max(axis=0) + 10 * r
    centers = np.vstack([bed.centers, far, far + [1.5 * r, 0, 0]])
    radii = np.r_[bed.radii, r, r]
    path = tmp_path_factory.mktemp("schema") / "bed.h5"
    amfe.write_bed(path, amfe.Bed(centers, radii, bed.attrs))
    return path


@pytest.fixture(scope="module")
def homogenized(bed_path):
    out = bed_path.parent / "r.json"
    proc = run_cli(["homogenize", str(bed_path), "-o", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def predicted(tmp_path_factory):
    path = tmp_path_factory.mktemp("predict") / "small.h5"
    assert run_cli(["pack", "-o", str(path), "--scale", "small", "--seed", "5"]).returncode == 0
    out = path.parent / "p.json"
    proc = run_cli(["predict", str(path), "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


def errors(result):
    return list(jsonschema.Draft202012Validator(load_schema()).iter_errors(result))


def test_the_schema_is_a_valid_draft_2020_12_schema():
    schema = load_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$defs"]["result"]["properties"]["schema_version"]["const"] == SCHEMA_VERSION


def test_homogenize_output_validates_and_its_header_is_right(homogenized, bed_path):
    r = homogenized
    assert errors(r) == []
    assert list(r)[:len(HEADER_KEYS)] == list(HEADER_KEYS)        # the header comes first
    assert r["command"] == "homogenize" and r["amfe_version"] == amfe.__version__
    with h5py.File(bed_path, "r") as f:                           # independent of amfe's reader
        centers, radii = f["particles/centers"][()], f["particles/radii"][()]
    h = hashlib.sha256(centers.astype("<f8").tobytes() + radii.astype("<f8").tobytes())
    assert r["input"] == {"path": str(bed_path), "sha256": h.hexdigest(),
                          "hash_of": r["input"]["hash_of"]}
    i, _ = find_pairs(centers, radii)
    assert r["counts"] == {"particles_input": len(radii), "particles_kept": len(radii) - 2,
                           "bonds_input": i.size, "bonds_kept": i.size - 1}
    assert r["n_removed"] == 2 and r["n_bonds"] == i.size - 1
    np.testing.assert_array_equal(r["box"]["min"], centers.min(axis=0))
    np.testing.assert_array_equal(r["box"]["max"], centers.max(axis=0))
    assert r["material"] == {"E": 210e9, "nu": 0.28, "psi": 0.08, "source": "bed file"}
    assert r["S_unit"] == "1/Pa" and r["units"]["modulus"] == "Pa"
    # the stated Poisson convention is the one the numbers follow
    S, p = np.array(r["S"]), r["properties"]
    assert r["poisson_convention"].startswith("nu_ij = -S_ji / S_ii")
    for name, (a, b) in {"nu_yz": (1, 2), "nu_xz": (0, 2), "nu_xy": (0, 1)}.items():
        assert p[name] == pytest.approx(-S[b, a] / S[a, a], rel=1e-12)


def test_material_source_says_where_the_material_came_from(bed_path):
    bed = amfe.read_bed(bed_path)
    plain = amfe.Bed(bed.centers, bed.radii)                      # no material attributes
    assert amfe.homogenize(plain).extra["material"]["source"] == "default (steel)"
    given = amfe.homogenize(plain, material=Material(E=70e9))
    assert given.extra["material"]["E"] == 70e9
    assert given.extra["material"]["source"] == "argument"
    assert given.extra["input"]["path"] is None
    assert errors(given.to_dict()) == []


@pytest.mark.parametrize("change", [
    lambda r: r.pop("schema_version"),
    lambda r: r.update(schema_version=2),
    lambda r: r.update(S_unit="Pa"),
    lambda r: r.update(poisson_convention="nu_ij = -S_ij / S_jj"),
    lambda r: r.update(bc="free"),
    lambda r: r["counts"].pop("bonds_kept"),
    lambda r: r["input"].update(sha256="abc"),
    lambda r: r["material"].update(source=""),
    lambda r: r["material"].pop("psi"),
    lambda r: r["solver"].update(rtol=10),
    lambda r: r.pop("C"),
    lambda r: r.update(warnings=[{"kind": "unconverged"}]),
])
def test_a_result_that_breaks_the_layout_fails(homogenized, change):
    r = copy.deepcopy(homogenized)
    change(r)
    assert errors(r)
    with pytest.raises(AmfeError, match="does not follow the schema"):
        validate(r)


def test_the_keys_other_issues_add_validate(homogenized):
    r = copy.deepcopy(homogenized)
    r["solver"].update(method="cholesky", reason="fill of the symbolic factorisation is low",
                       converged_reasons=["CONVERGED_RTOL"] * 6, options_left=["-foo_bar"])
    r["warnings"] = ["load case xx missed the convergence contract (accepted)",
                     "PETSc options never used: -foo_bar"]
    r["bc"] = "subc"
    assert errors(r) == []


def test_the_bounds_report_validates(bed_path):
    out = bed_path.parent / "all.json"
    proc = run_cli(["homogenize", str(bed_path), "--bc", "all", "-o", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    r = json.loads(out.read_text())
    assert errors(r) == []
    assert r["command"] == "homogenize" and r["input"]["path"] == str(bed_path)
    assert set(r["conditions"]) == {"kubc", "subc"}
    assert all(c["counts"]["bonds_kept"] == c["n_bonds"] for c in r["conditions"].values())
    for change in (lambda d: d["conditions"].pop("subc"),
                   lambda d: d["conditions"]["kubc"].pop("material"),
                   lambda d: d.update(bc="kubc")):
        wrong = copy.deepcopy(r)
        change(wrong)
        assert errors(wrong)


def test_predict_output_validates_with_its_own_block(predicted):
    p = predicted
    assert errors(p) == []
    assert p["command"] == "predict" and p["counts"]["particles_input"] > 0
    block = p["predict"]
    assert block["model"]["members"] == p["members"] and block["source"] == p["source"]
    assert block["spread"]["relative"] == p["spread"]
    assert block["flags"]["flagged"] == p["flagged"]
    assert block["flags"]["reasons"] == p["flag_reasons"]
    assert block["flags"]["fill_value"] == p["fill"]
    no_block = {k: v for k, v in p.items() if k != "predict"}
    assert errors(no_block)
    wrong = copy.deepcopy(p)
    wrong["predict"]["flags"].pop("spread")
    assert errors(wrong)

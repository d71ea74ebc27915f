"""Issue 47's continuum springs: their limits, their parameter file, and --springs end to end.

The form (amfe.model.continuum_springs, docs/model.md section 11) puts a body compliance
in series with each paper spring and grows the neck by (1 + alpha phi); both vanish with
the necks, so at a small a* the springs must reduce to the paper's and so to the rigid
punch limits of two half-spaces (k_n -> E a / (1 - nu^2), k_t -> 2 E a / ((2 - nu)(1 + nu)),
kappa_n -> 8 E a^3 / ((2 - nu)(1 + nu)), kappa_t -> 2 E a^3 / (1 - nu^2)).
"""
import json

import h5py
import numpy as np
import pytest

import amfe
from amfe.cli import main
from amfe.errors import AmfeError
from amfe.model.bonds import contact_geometry
from amfe.model.continuum_springs import (
    ContinuumSprings,
    body_springs,
    load_params,
    neck_share,
    springs_of_record,
    springs_record,
)
from amfe.model.material import STEEL
from amfe.model.scales import bed_for
from amfe.model.springs import spring_constants
from amfe.vocab import LABEL_NAMES

STRONG = ContinuumSprings(beta_n=0.5, beta_t=0.7, alpha=0.4)


def _pair(a_star, R=1.0):
    """Two equal spheres of radius R whose neck has a* = a / r_eff (r_eff = R / 2)."""
    a = a_star * R / 2
    d = np.sqrt(R**2 - a**2)
    centers = np.array([[0.0, 0.0, 0.0], [2 * d, 0.0, 0.0]])
    radii = np.array([R, R])
    return contact_geometry(centers, radii, np.array([0]), np.array([1])), radii


@pytest.mark.parametrize("a_star", [1e-3, 1e-4])
def test_small_necks_reduce_to_the_rigid_punch_limits(a_star):
    bonds, radii = _pair(a_star)
    E, nu = STEEL.E, STEEL.nu
    paper = spring_constants(bonds.a, bonds.r_eff, STEEL)
    got = body_springs(paper, bonds.i, bonds.j, bonds.a, radii, E, STRONG)
    a = bonds.a[0]
    limits = (E * a / (1 - nu**2), 2 * E * a / ((2 - nu) * (1 + nu)),
              8 * E * a**3 / ((2 - nu) * (1 + nu)), 2 * E * a**3 / (1 - nu**2))
    for k, limit in zip(got, limits):
        # the corrections are O(a*): within a few a* of the limit, closer as a* falls
        assert abs(k[0] / limit - 1) < 5 * a_star


def test_large_necks_are_softer_and_zero_parameters_give_the_papers():
    bonds, radii = _pair(0.6)
    paper = spring_constants(bonds.a, bonds.r_eff, STEEL)
    same = body_springs(paper, bonds.i, bonds.j, bonds.a, radii, STEEL.E,
                        ContinuumSprings(0.0, 0.0, 0.0))
    assert all(np.array_equal(p, s) for p, s in zip(paper, same))
    soft = body_springs(paper, bonds.i, bonds.j, bonds.a, radii, STEEL.E,
                        ContinuumSprings(0.5, 0.5, 0.0))
    # series compliance by hand: 1/k = 1/k_paper + beta (c_i + c_j), c = phi / (E R^m)
    phi = bonds.a[0] / radii[0]
    for m, (p, s) in zip((1, 1, 3, 3), zip(paper, soft)):
        body = 2 * phi / (STEEL.E * radii[0]**m)
        assert s[0] == pytest.approx(1 / (1 / p[0] + 0.5 * body), rel=1e-12)


def test_neck_share_sums_each_particles_necks():
    i, j = np.array([0, 0, 1]), np.array([1, 2, 2])
    a = np.array([0.1, 0.2, 0.3])
    radii = np.array([1.0, 2.0, 0.5])
    assert np.allclose(neck_share(i, j, a, radii), [0.3 / 1.0, 0.4 / 2.0, 0.5 / 0.5])


def test_the_parameter_file_is_versioned(tmp_path):
    shipped = load_params()
    assert shipped.beta_n > 0 and shipped.beta_t > 0 and shipped.version != "unfitted"
    data = json.loads(load_params.__globals__["PARAMS_FILE"].read_text())
    for change, message in (({"format": 2}, "format 2"), ({"beta_n": -1.0}, "beta_n"),
                            ({"format": None}, "format None")):
        bad = tmp_path / "p.json"
        bad.write_text(json.dumps({**data, **change}))
        with pytest.raises(AmfeError, match=message):
            load_params(bad)
    with pytest.raises(AmfeError, match="missing"):
        load_params(tmp_path / "none.json")
    # a record gives back the very springs it describes
    assert springs_of_record(json.dumps(springs_record("continuum"))) == shipped
    assert springs_of_record(None) == "paper" == springs_of_record({"name": "paper"})


def test_homogenize_records_the_springs_and_the_voxel_model_refuses_them():
    bed = bed_for("tiny", 7)
    paper = amfe.homogenize(bed)
    cont = amfe.homogenize(bed, springs="continuum")
    assert paper.extra["springs"] == {"name": "paper"}
    assert cont.extra["springs"]["name"] == "continuum"
    assert cont.extra["springs"]["beta_n"] == load_params().beta_n
    assert not np.isclose(cont.Ex, paper.Ex, rtol=1e-3)
    with pytest.raises(AmfeError, match="springs"):
        amfe.homogenize(bed, springs="stiff")
    with pytest.raises(AmfeError, match="voxel model"):
        amfe.homogenize(bed, springs="continuum", model="voxel")


def test_springs_reach_the_data_set_its_labels_and_the_command_line(tmp_path, capsys):
    out = tmp_path / "d.h5"
    assert main(["dataset", "-o", str(out), "--count", "3", "--seed", "5", "--scale", "tiny",
                 "--max-failed-share", "1", "--no-progress", "--springs", "continuum"]) == 0
    with h5py.File(out, "r") as f:
        recorded = json.loads(f.attrs["springs"])
        status, labels = f["status"][:], f["labels"][:]
        seeds = f["seed"][:]
    assert recorded == springs_record("continuum")
    # a finished continuum data set grows with the same springs, and refuses others
    assert main(["dataset", "-o", str(out), "--count", "4", "--seed", "5", "--scale", "tiny",
                 "--max-failed-share", "1", "--no-progress", "--springs", "continuum"]) == 0
    with h5py.File(out, "r") as f:
        assert f["labels"].shape[0] == 4
        assert np.array_equal(f["labels"][:3], labels, equal_nan=True)
        labels = f["labels"][:]
    assert main(["dataset", "-o", str(out), "--count", "5", "--seed", "5", "--scale", "tiny",
                 "--max-failed-share", "1", "--no-progress"]) == 2
    assert "springs" in capsys.readouterr().err
    k = int(np.flatnonzero(status == 0)[0])
    bed = bed_for("tiny", int(seeds[k]))
    want = amfe.homogenize(bed, springs="continuum", rtol=1e-8)
    assert np.allclose(labels[k], [want.properties[n] for n in LABEL_NAMES], rtol=1e-6)
    # the command line's homogenize writes the same choice into its JSON
    bed_path, res = tmp_path / "bed.h5", tmp_path / "r.json"
    amfe.write_bed(bed_path, bed)
    capsys.readouterr()
    assert main(["homogenize", str(bed_path), "-o", str(res), "--quiet", "--springs",
                 "continuum"]) == 0
    assert json.loads(res.read_text())["springs"] == springs_record("continuum")
    # the printout says what these springs do not follow, and where to go for it
    printed = capsys.readouterr().out
    assert "springs: continuum (fit " in printed and "use --model voxel" in printed
    assert main(["homogenize", str(bed_path), "--quiet"]) == 0
    assert "springs:" not in capsys.readouterr().out
    # its label table is named apart, keeps the springs, and rebuilds the same labels
    shards = tmp_path / "labels"
    shards.mkdir()
    assert main(["dataset", "--export-labels", str(out), "-o", str(shards)]) == 0
    (table,) = shards.iterdir()
    assert table.name == "tiny_continuum_seed5_labels_00000000-00000004.h5"
    with h5py.File(table, "r") as f:
        assert json.loads(f.attrs["springs"]) == recorded
    again = tmp_path / "again.h5"
    assert main(["dataset", "--from-labels", str(table), "-o", str(again), "--no-progress",
                 "--max-failed-share", "1"]) == 0
    with h5py.File(again, "r") as f:
        assert json.loads(f.attrs["springs"]) == recorded
        assert np.array_equal(f["labels"][:], labels, equal_nan=True)
    capsys.readouterr()


def test_a_bed_outside_the_fits_range_is_warned_and_one_inside_is_not():
    bed = bed_for("tiny", 7)
    inside = ContinuumSprings(0.1, 0.2, 1.0, phi_range=(0.0, 100.0))
    outside = ContinuumSprings(0.1, 0.2, 1.0, phi_range=(50.0, 100.0))
    assert not [w for w in amfe.homogenize(bed, springs=inside).extra["warnings"]
                if "neck share" in w]
    warned = [w for w in amfe.homogenize(bed, springs=outside).extra["warnings"]
              if "neck share" in w]
    assert len(warned) == 1 and "--model voxel" in warned[0]


def test_a_bed_outside_the_fits_solid_fractions_is_warned_once_and_one_inside_is_not(capfd):
    """The fit's solid fractions (the shipped file's 0.2-0.8) are where the springs hold; a
    bed outside them is told to use the voxel model, in the result and once on the terminal,
    whatever its neck share (the sparse beds' lie inside the fit's neck shares)."""
    assert load_params().fraction_range == (0.2, 0.8)
    bed = bed_for("tiny", 7)
    fraction = amfe.homogenize(bed).extra["density"]["solid_fraction"]
    inside = ContinuumSprings(0.1, 0.2, 1.0, fraction_range=(fraction - 0.01, fraction + 0.01))
    above = ContinuumSprings(0.1, 0.2, 1.0, fraction_range=(0.0, fraction - 0.01))
    capfd.readouterr()
    assert not [w for w in amfe.homogenize(bed, springs=inside).extra["warnings"]
                if "solid fraction" in w]
    warned = [w for w in amfe.homogenize(bed, springs=above).extra["warnings"]
              if "solid fraction" in w]
    assert len(warned) == 1 and "--model voxel" in warned[0] and f"{fraction:.3f}" in warned[0]
    assert capfd.readouterr().err.count("solid fractions") == 1
    assert not [w for w in amfe.homogenize(bed, springs="paper").extra["warnings"]
                if "solid fraction" in w]


def test_the_continuum_moduli_scale_exactly_with_E_and_not_with_the_length_unit():
    """Every continuum spring is E times a function of the geometry (the body's compliance
    is phi / (E R^m)): half the E halves the moduli and keeps the Poisson ratios, which is
    what lets amfe predict scale a bed of another E (docs/surrogate.md); and a bed given in
    other lengths (all of it x 1000) has the same constants."""
    bed = bed_for("tiny", 7)
    steel = amfe.homogenize(bed, springs="continuum", rtol=1e-12)
    half = amfe.homogenize(bed, springs="continuum", rtol=1e-12,
                           material={"E": STEEL.E / 2, "nu": STEEL.nu, "psi": STEEL.psi})
    for name in LABEL_NAMES:
        factor = 0.5 if name.startswith("E") else 1.0
        assert half.properties[name] == pytest.approx(factor * steel.properties[name],
                                                      rel=1e-7), name
    big = amfe.Bed(bed.centers * 1e3, bed.radii * 1e3,
                   {**bed.attrs, "size": [s * 1e3 for s in bed.attrs["size"]]})
    scaled = amfe.homogenize(big, springs="continuum", rtol=1e-12)
    for name in LABEL_NAMES:
        assert scaled.properties[name] == pytest.approx(steel.properties[name], rel=1e-7), name

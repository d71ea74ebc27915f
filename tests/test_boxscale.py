"""Box scales (issue 46): `amfe dataset --size X Y Z` and drawn or alloy materials.

Tiny boxes (0.15 x 0.15 mm, two layers) keep every run to a second or two. A box
scale's name is its whole distribution (amfe.model.boxscale); these tests check
that it round-trips through a label table, that a record is the bed `amfe pack
--scale NAME --seed <its seed>` makes, that a shard or part of another spec is
refused, that a partial layer is refused, that the old scales are untouched,
and that the moduli scale exactly with E.
"""
import h5py
import numpy as np
import pytest
from helpers import run_cli

from amfe.dataset.labels import read_tables
from amfe.errors import AmfeError
from amfe.io.bedfile import read_bed
from amfe.model.boxscale import DEFAULT_NU, DEFAULT_PSI, a_star_cap, box_name, parse_box
from amfe.model.material import ALLOYS, STEEL, Material
from amfe.model.scales import (
    PARAM_NAMES,
    SCALES,
    bed_for,
    get_scale,
    param_record,
    record_seed,
    sample_bed_params,
)

DRAW = "box150x150x200um_nu250to400psi40to120"
SEED, COUNT = 46099, 4


def ok(proc):
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """(data set of the drawn-material tiny box, its label table, its rebuild)."""
    d = tmp_path_factory.mktemp("box")
    data, table, rebuilt = d / "box.h5", d / "box_labels.h5", d / "rebuilt.h5"
    ok(run_cli(["dataset", "-o", str(data), "--count", str(COUNT), "--seed", str(SEED),
                "--size", "0.15", "0.15", "0.2", "--materials", "draw", "--no-progress"]))
    ok(run_cli(["dataset", "--export-labels", str(data), "-o", str(table)]))
    ok(run_cli(["dataset", "--from-labels", str(table), "-o", str(rebuilt), "--no-progress"]))
    return data, table, rebuilt


def rows(path):
    with h5py.File(path, "r") as f:
        out = {k: f[k][()] for k in ("images", "bond_images", "labels", "C", "seed", "status")}
        out["params"] = {n: f["params"][n][()] for n in f["params"]}
        out["attrs"] = dict(f.attrs)
    return out


def test_names_are_canonical_and_checked():
    assert box_name((0.6, 0.6, 0.3)) == "box600x600x300um"
    assert box_name((0.6, 0.6, 0.3), "Ti64") == "box600x600x300um_Ti64"
    assert box_name((0.15, 0.15, 0.2), "draw") == DRAW
    assert box_name((0.9, 0.9, 0.3), nu=(0.3, 0.35)) == "box900x900x300um_nu300to350psi40to120"
    for name in (DRAW, "box2000x2000x600um", "box600x600x300um_AlSi10Mg"):
        assert parse_box(name).name == name
    for bad in ("box0600x600x300um", "box600x600x300um_steel", "box600x600x300um_Ti6Al4V",
                "box600x600x300um_nu400to250psi40to120", "box600x600x250um"):
        with pytest.raises(AmfeError):
            get_scale(bad)
    sc = parse_box("box2000x2000x300um")
    assert sc.image_shape == (3, 66, 66)       # 2 mm = 66 whole cells + a cropped 0.02 mm strip
    assert sc.image_box[:2] == (66 * 30e-6, 66 * 30e-6) and sc.size[0] == 2e-3


@pytest.mark.parametrize("z", ["0.25", "0.05", "1.1"])
def test_a_partial_or_out_of_range_layer_is_refused(tmp_path, z):
    proc = run_cli(["dataset", "-o", str(tmp_path / "d.h5"), "--count", "2",
                    "--size", "0.6", "0.6", z])
    assert proc.returncode == 2 and "whole number of layers" in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and not (tmp_path / "d.h5").exists()


def test_old_scales_are_untouched():
    """The old scales draw no material (steel, as before), image their full box, and
    box600x600x300um makes small's beds bit for bit."""
    for name, sc in SCALES.items():
        assert sc.image_box == sc.size and sc.material == "steel"
        params = sample_bed_params(name, 12345)
        assert "material" not in params and params["a_star_max"] == 0.98
        rec = param_record(params)
        assert (rec["E"], rec["nu"], rec["psi"]) == (STEEL.E, STEEL.nu, STEEL.psi)
    assert [n for n in PARAM_NAMES[-3:]] == ["E", "nu", "psi"]
    a, b = bed_for("small", 777), bed_for("box600x600x300um", 777)
    assert np.array_equal(a.centers, b.centers) and np.array_equal(a.radii, b.radii)


def test_drawn_materials_and_the_critical_a_star():
    sc = get_scale(DRAW)
    mats = [sample_bed_params(sc, record_seed(1, k))["material"] for k in range(200)]
    nu = np.array([m.nu for m in mats])
    psi = np.array([m.psi for m in mats])
    assert DEFAULT_NU[0] <= nu.min() and nu.max() <= DEFAULT_NU[1] and np.ptp(nu) > 0.1
    assert DEFAULT_PSI[0] <= psi.min() and psi.max() <= DEFAULT_PSI[1] and np.ptp(psi) > 0.05
    assert all(m.E == STEEL.E for m in mats)
    # the same draws for the same seed; the geometry draws are those of the steel box
    p1, p2 = sample_bed_params(sc, 42), sample_bed_params("box150x150x200um", 42)
    assert p1["material"] == sample_bed_params(sc, 42)["material"]
    assert p1["scan"] == p2["scan"] and p1["enlargement"] == p2["enlargement"]
    # the bound is 0.98 where the critical a* is 0.985 or more, 0.005 below it elsewhere
    from amfe.model.springs import critical_a_star
    assert a_star_cap(0.98, Material(nu=0.25, psi=0.11)) == 0.98
    assert a_star_cap(0.98, Material(nu=0.40, psi=0.12)) == 0.98
    corner = a_star_cap(0.98, Material(nu=0.25, psi=0.12))
    assert corner == critical_a_star(0.25, 0.12) - 0.005 and 0.9798 < corner < 0.98
    cap = a_star_cap(0.98, Material(nu=0.25, psi=0.2))
    assert cap == pytest.approx(critical_a_star(0.25, 0.2) - 0.005) and cap < 0.96
    bed = bed_for(box_name((0.15, 0.15, 0.1), nu=(0.25, 0.25), psi=(0.2, 0.2)), 3)
    assert bed.attrs["a_star_max"] == cap and bed.material().psi == 0.2


def test_the_spec_round_trips_through_a_label_table(made):
    data, table, rebuilt = made
    t = read_tables([table])
    assert t["attrs"]["scale"] == DRAW and t["attrs"]["dataset_seed"] == SEED
    a, b = rows(data), rows(rebuilt)
    assert a["attrs"]["scale"] == b["attrs"]["scale"] == DRAW
    assert a["images"].shape[1:] == (2, 5, 5)
    for key in ("images", "bond_images", "labels", "C", "seed", "status"):
        assert np.array_equal(a[key], b[key], equal_nan=True), key
    for n in ("E", "nu", "psi"):
        assert np.array_equal(a["params"][n], b["params"][n]), n
    assert np.all(a["status"] == 0) and np.unique(a["params"]["nu"]).size == COUNT
    ok(run_cli(["dataset", "--check", str(data)]))


def test_a_record_is_the_bed_amfe_pack_makes(made, tmp_path):
    from amfe.dataset.images import pixelate
    data = rows(made[0])
    sc = get_scale(DRAW)
    for k in (0, 3):
        bed_path = tmp_path / f"bed{k}.h5"
        ok(run_cli(["pack", "--scale", DRAW, "--seed", str(int(data["seed"][k])), "-o",
                    str(bed_path)]))
        bed = read_bed(str(bed_path))
        m = bed.material()
        assert (m.E, m.nu, m.psi) == (data["params"]["E"][k], data["params"]["nu"][k],
                                      data["params"]["psi"][k])
        image = pixelate(bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                         box=((0.0, 0.0, 0.0), sc.image_box), spacing=sc.image_spacing)
        assert np.array_equal(np.asarray(image, np.float32), data["images"][k])


def test_a_table_of_another_spec_is_refused(made, tmp_path):
    table = made[1]
    other = tmp_path / "other.h5"
    ok(run_cli(["dataset", "-o", str(other), "--count", "2", "--seed", str(SEED),
                "--size", "0.15", "0.15", "0.2", "--materials", "Ti64", "--no-progress"]))
    shard = tmp_path / "other_labels.h5"
    ok(run_cli(["dataset", "--export-labels", str(other), "-o", str(shard)]))
    with pytest.raises(AmfeError, match="another data set"):
        read_tables([table, shard])
    proc = run_cli(["dataset", "--from-labels", str(table), "--size", "0.15", "0.15", "0.2",
                    "-o", str(tmp_path / "x.h5")])
    assert proc.returncode == 2 and "--size" in proc.stderr
    # the same output with another spec: the finished file refuses the run
    proc = run_cli(["dataset", "-o", str(other), "--count", "2", "--seed", str(SEED),
                    "--size", "0.15", "0.15", "0.2", "--materials", "IN718"])
    assert proc.returncode == 2 and "other parameters" in proc.stderr, proc.stderr


def test_check_refuses_a_material_the_spec_does_not_make(made, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(made[0].read_bytes())
    with h5py.File(bad, "r+") as f:
        nu = f["params/nu"][()]
        nu[1] = 0.45
        f["params/nu"][...] = nu
    proc = run_cli(["dataset", "--check", str(bad)])
    assert proc.returncode == 1 and "material" in proc.stderr, proc.stderr


def test_alloys_are_fixed_per_scale():
    sc = get_scale("box600x600x300um_IN718")
    assert sample_bed_params(sc, 1)["material"] is ALLOYS["IN718"]
    assert sample_bed_params(sc, 2)["material"] is ALLOYS["IN718"]


def test_moduli_scale_exactly_with_E():
    """Every spring is E times a function of a*, R, nu and psi: two solves that differ only
    in E give moduli in the ratio E2/E1 (to 1e-12) and the same Poisson ratios."""
    from amfe.model.options import SolveOptions
    from solvers.driver import homogenize_bed

    bed = bed_for(box_name((0.15, 0.15, 0.2), nu=(0.33, 0.33), psi=(0.1, 0.1)), 8)
    base = bed.material()
    out = []
    for E in (base.E, ALLOYS["Ti64"].E):
        mat = Material(E=E, nu=base.nu, psi=base.psi)
        res = homogenize_bed(bed, SolveOptions(material=mat, solver="cholesky")).to_dict()
        out.append(res)
    ratio = ALLOYS["Ti64"].E / base.E
    p1, p2 = out[0]["properties"], out[1]["properties"]
    for n in ("Ex", "Ey", "Ez"):
        assert p2[n] / p1[n] == pytest.approx(ratio, rel=1e-12, abs=0)
    for n in ("nu_yz", "nu_xz", "nu_xy"):
        assert p2[n] == pytest.approx(p1[n], rel=1e-12, abs=0)
    C1, C2 = np.array(out[0]["C"]), np.array(out[1]["C"])
    assert np.max(np.abs(C2 - ratio * C1)) <= 1e-12 * np.max(np.abs(C2))


def test_a_side_of_no_whole_cells_is_cropped_as_the_surrogate_reads_it(tmp_path):
    """0.16 x 0.17 mm: 5 x 5 whole cells, the strips cropped; the record's image is the one
    training/imagebox.py's whole-cell rule makes of the same bed."""
    from amfe.training.imagebox import cropped_box, image_any_size

    name = box_name((0.16, 0.17, 0.3), "AlSi10Mg")
    sc = get_scale(name)
    assert sc.image_shape == (3, 5, 5) and sc.image_box == cropped_box(sc.size, sc.cell)
    assert sc.image_box[:2] == pytest.approx((0.15e-3, 0.15e-3), rel=1e-12)
    out = tmp_path / "d.h5"
    ok(run_cli(["dataset", "-o", str(out), "--count", "2", "--seed", "5", "--size", "0.16",
                "0.17", "0.3", "--materials", "AlSi10Mg", "--no-progress"]))
    data = rows(out)
    assert data["attrs"]["scale"] == name
    for k in range(2):
        bed = bed_for(name, int(data["seed"][k]))
        image, box = image_any_size(bed, bed.attrs["size"], sc.cell, sc.layer_thickness,
                                    sc.image_spacing)
        assert box == sc.image_box and np.array_equal(image, data["images"][k])
        assert data["params"]["E"][k] == ALLOYS["AlSi10Mg"].E


@pytest.mark.mpi
def test_records_do_not_depend_on_the_rank_count(made, tmp_path):
    out = tmp_path / "two.h5"
    ok(run_cli(["dataset", "-o", str(out), "--count", str(COUNT), "--seed", str(SEED),
                "--size", "0.15", "0.15", "0.2", "--materials", "draw", "--no-progress"],
               ranks=2))
    a, b = rows(made[0]), rows(out)
    for key in ("images", "bond_images", "labels", "C", "seed"):
        assert np.array_equal(a[key], b[key]), key
    for n in ("E", "nu", "psi", "a_star_max", "track_width"):
        assert np.array_equal(a["params"][n], b["params"][n], equal_nan=True), n


def test_parts_written_before_the_material_columns_read_as_steel():
    from amfe.dataset.merge import _padded
    old = np.arange(len(PARAM_NAMES) - 3, dtype=float)
    row = _padded(old)
    assert row.shape == (len(PARAM_NAMES),) and np.array_equal(row[:-3], old)
    assert tuple(row[-3:]) == (STEEL.E, STEEL.nu, STEEL.psi)
    new = np.arange(len(PARAM_NAMES), dtype=float)
    assert np.array_equal(_padded(new), new)

"""V's box and the density in every result (issue 48, items 3 and 4).

The result says which box V is and where it came from (``volume_box``), and the
solid fraction of that box (``density``), for the frame as for the voxel model;
``--box`` / ``box=`` sets V; a bed in another unit than metres is warned about.
Checks: V's box moves C exactly as 1/V (the moments do not depend on V), the
density against an independent Monte Carlo estimate (periodic images
included), the same box and density from the frame and the voxel model, and
unit invariance of the constants with the warning.
"""
import json
import os

import numpy as np
import pytest
from helpers import run_cli

import amfe
from amfe.errors import AmfeError
from amfe.model.bed import Bed

BED = dict(size=(150e-6, 150e-6, 100e-6), seed=3)


@pytest.fixture(scope="module")
def bed():
    return amfe.generate_bed(**BED)


@pytest.fixture(scope="module")
def recorded(bed):
    return amfe.homogenize(bed, rtol=1e-10, solver="gamg")


def monte_carlo_fraction(centers, radii, lo, size, n=400_000, period=None, seed=0):
    """(fraction, standard error) of [lo, lo + size] inside the union of the spheres, by
    uniform points; ``period`` (3,): distances by the minimum image."""
    rng = np.random.default_rng(seed)
    pts = lo + rng.random((n, 3)) * size
    inside = np.zeros(n, bool)
    for c, r in zip(centers, radii):
        d = pts - c
        if period is not None:
            d -= period * np.round(d / period)
        inside |= np.einsum("ij,ij->i", d, d) < r * r
    p = inside.mean()
    return p, np.sqrt(p * (1 - p) / n)


def test_recorded_size_is_v_and_its_density_matches_monte_carlo(bed, recorded):
    box = recorded.extra["volume_box"]
    assert box["source"] == "recorded size" and box["note"] is None
    np.testing.assert_allclose(box["size"], BED["size"], rtol=1e-15)
    assert box["lo"] == [0.0, 0.0, 0.0]
    assert box["V"] == pytest.approx(recorded.volume, rel=1e-14)
    d = recorded.extra["density"]
    p, se = monte_carlo_fraction(bed.centers, bed.radii, np.zeros(3), np.array(BED["size"]))
    assert abs(d["solid_fraction"] - p) < 4 * se + d["precision"]
    assert d["relative_density"] == d["solid_fraction"]
    assert d["density"] == pytest.approx(d["solid_fraction"] * 7800.0, rel=1e-12)


def test_without_a_recorded_size_v_is_the_spheres_box_and_c_scales_as_1_over_v(bed, recorded):
    bare = Bed(bed.centers, bed.radii)                    # a file another program wrote
    res = amfe.homogenize(bare, rtol=1e-10, solver="gamg")
    box = res.extra["volume_box"]
    assert box["source"] == "spheres' box"
    lo = (bed.centers - bed.radii[:, None]).min(axis=0)
    hi = (bed.centers + bed.radii[:, None]).max(axis=0)
    np.testing.assert_allclose(box["lo"], lo, rtol=1e-12)
    np.testing.assert_allclose(box["size"], hi - lo, rtol=1e-12)
    # the same moments over another V: C x V is the same matrix
    np.testing.assert_allclose(np.asarray(res.C) * res.volume,
                               np.asarray(recorded.C) * recorded.volume,
                               rtol=0, atol=1e-8 * np.abs(recorded.C).max() * recorded.volume)
    p, se = monte_carlo_fraction(bed.centers, bed.radii, lo, hi - lo, seed=3)
    assert abs(res.extra["density"]["solid_fraction"] - p) < 4 * se + 1e-3


def test_a_given_box_is_v_centred_on_the_centres(bed, recorded):
    given = (160e-6, 170e-6, 110e-6)
    res = amfe.homogenize(bed, rtol=1e-10, solver="gamg", box=given)
    box = res.extra["volume_box"]
    assert box["source"] == "given box" and box["V"] == pytest.approx(np.prod(given), rel=1e-14)
    mid = 0.5 * (bed.centers.min(axis=0) + bed.centers.max(axis=0))
    np.testing.assert_allclose(np.asarray(box["lo"]) + 0.5 * np.asarray(given), mid, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(res.C) * res.volume,
                               np.asarray(recorded.C) * recorded.volume,
                               rtol=0, atol=1e-8 * np.abs(recorded.C).max() * recorded.volume)
    p, se = monte_carlo_fraction(bed.centers, bed.radii, np.asarray(box["lo"]),
                                 np.asarray(given), seed=1)
    assert abs(res.extra["density"]["solid_fraction"] - p) < 4 * se + 1e-3


@pytest.mark.parametrize("box, message", [
    ((50e-6, 50e-6, 50e-6), "does not hold the load-carrying centres"),
    ((1e-4, -1e-4, 1e-4), "three positive lengths"),
    ((1e-4, 1e-4), "three positive lengths")])
def test_a_bad_box_is_refused(bed, box, message):
    with pytest.raises(AmfeError, match=message):
        amfe.homogenize(bed, box=box)


def test_a_periodic_bed_counts_its_images_and_refuses_a_box():
    bed = amfe.generate_bed((100e-6, 100e-6, 100e-6), seed=2, periodic=True)
    res = amfe.homogenize(bed, bc="periodic")
    box = res.extra["volume_box"]
    assert box["source"] == "periodic box"
    period = np.asarray(bed.attrs["periodic"], float)
    np.testing.assert_allclose(box["size"], period, rtol=1e-15)
    p, se = monte_carlo_fraction(bed.centers, bed.radii, np.asarray(box["lo"]), period,
                                 period=period, seed=2)
    assert abs(res.extra["density"]["solid_fraction"] - p) < 4 * se + 1e-3
    with pytest.raises(AmfeError, match="periodic bed's box"):
        amfe.homogenize(bed, bc="periodic", box=tuple(period))


def test_the_voxel_model_has_the_frames_box_and_density(bed, recorded):
    vox = amfe.homogenize(bed, model="voxel")
    assert vox.extra["volume_box"]["source"] == "recorded size"
    np.testing.assert_allclose(vox.extra["volume_box"]["size"],
                               recorded.extra["volume_box"]["size"], rtol=1e-12)
    assert vox.extra["density"]["solid_fraction"] == pytest.approx(
        recorded.extra["density"]["solid_fraction"], abs=1e-12)


def test_a_bed_in_micrometres_is_warned_about_and_gives_the_same_constants(bed, recorded):
    micro = Bed(bed.centers * 1e6, bed.radii * 1e6,
                attrs={"size": np.asarray(BED["size"]) * 1e6})
    res = amfe.homogenize(micro, rtol=1e-10, solver="gamg")
    assert any("micrometres" in w for w in res.extra["warnings"])
    assert not any("micrometres" in w for w in recorded.extra["warnings"])
    for name in ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy"):
        assert res.properties[name] == pytest.approx(recorded.properties[name], rel=1e-8)


def test_the_command_line_prints_and_writes_v_its_source_and_the_density(tmp_path, bed):
    path = str(tmp_path / "bed.h5")
    amfe.write_bed(path, bed)
    out = run_cli(["homogenize", path, "--box", "0.16mm", "160um", "1e-4", "-o",
                   str(tmp_path / "r.json"), "--quiet"])
    assert out.returncode == 0, out.stderr
    assert "the given box 0.16 x 0.16 x 0.1 mm; solid fraction (relative density) 0." in out.stdout
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["volume_box"]["source"] == "given box"
    assert data["volume"] == pytest.approx(0.16e-3 * 0.16e-3 * 0.1e-3, rel=1e-14)
    back = amfe.read_result(str(tmp_path / "r.json"))
    assert back.extra["volume_box"] == data["volume_box"]
    assert back.extra["density"] == data["density"]
    bad = run_cli(["homogenize", path, "--box", "0.05mm", "0.05mm", "0.05mm", "--quiet"])
    assert bad.returncode != 0 and "does not hold" in bad.stderr
    assert "Traceback" not in bad.stderr
    assert not os.path.exists(tmp_path / "none.json")

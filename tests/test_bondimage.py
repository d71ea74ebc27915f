"""The bond-stiffness image (amfe.dataset.bondimage): analytic pixels, sums, unit invariance."""
import numpy as np
import pytest

from amfe.dataset.bondimage import bond_image, bond_image_of
from amfe.model.bonds import bond_springs, find_bonds
from amfe.model.material import STEEL, Material
from amfe.model.scales import bed_for, get_scale, record_seed
from amfe.model.springs import spring_constants

CELL = (30e-6, 30e-6)
T = 100e-6


def test_two_spheres_analytic_pixel():
    # equal spheres R at distance L: contact radius sqrt(R^2 - L^2/4), effective radius R/2
    R, L = 20e-6, 36e-6
    mid = np.array([45e-6, 75e-6, 150e-6])          # in cell x 1, y 2, layer 1
    c = np.array([mid - [L / 2, 0, 0], mid + [L / 2, 0, 0]])
    img = bond_image_of(c, np.full(2, R), STEEL, np.zeros(3), [90e-6, 90e-6, 200e-6], CELL, T)
    assert img.shape == (2, 3, 3)
    a = np.sqrt(R**2 - L**2 / 4)
    k_n = spring_constants(np.array([a]), np.array([R / 2]), STEEL)[0][0]
    want = k_n * L**2 / (STEEL.E * CELL[0] * CELL[1] * T)
    assert img[1, 2, 1] == pytest.approx(want, rel=1e-6)
    img[1, 2, 1] = 0
    assert not img.any()


def test_partial_cell_and_midpoint_outside_box():
    R, L = 20e-6, 36e-6
    # box 0..50 um in x: the second column is a partial cell of 20 um
    mid = np.array([40e-6, 15e-6, 50e-6])
    c = np.array([mid - [0, 0, L / 2], mid + [0, 0, L / 2]])
    img = bond_image_of(c, np.full(2, R), STEEL, np.zeros(3), [50e-6, 30e-6, 100e-6], CELL, T)
    assert img.shape == (1, 1, 2)
    a = np.sqrt(R**2 - L**2 / 4)
    k_n = spring_constants(np.array([a]), np.array([R / 2]), STEEL)[0][0]
    assert img[0, 0, 1] == pytest.approx(k_n * L**2 / (STEEL.E * 20e-6 * 30e-6 * T), rel=1e-6)
    # the same pair with its midpoint beyond the box's far face in x is left out
    img = bond_image_of(c + [20e-6, 0, 0], np.full(2, R), STEEL, np.zeros(3),
                        [50e-6, 30e-6, 100e-6], CELL, T)
    assert not img.any()


@pytest.fixture(scope="module")
def small_bed():
    return bed_for(get_scale("small"), record_seed(1, 0))


def test_sum_is_the_bonds_voigt_stiffness(small_bed):
    sc = get_scale("small")
    img = bond_image(small_bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                     box=((0.0, 0.0, 0.0), sc.size))
    assert img.shape == sc.image_shape and img.min() >= 0
    b = find_bonds(small_bed.centers, small_bed.radii)
    k_n = bond_springs(b, small_bed.material())[0]
    mid = 0.5 * (small_bed.centers[b.i] + small_bed.centers[b.j])
    inside = np.all((mid >= 0) & (mid < np.asarray(sc.size)), axis=1)
    v_cell = sc.cell[0] * sc.cell[1] * sc.layer_thickness
    total = img.astype(np.float64).sum() * v_cell * small_bed.material().E
    assert total == pytest.approx(np.sum((k_n * b.length**2)[inside]), rel=1e-5)
    assert 0.3 < img.mean() < 3   # the documented range of a small bed's mean


def test_unit_and_translation_invariance(small_bed):
    sc = get_scale("small")
    lo, hi = np.zeros(3), np.asarray(sc.size)
    ref = bond_image_of(small_bed.centers, small_bed.radii, STEEL, lo, hi, sc.cell,
                        sc.layer_thickness)
    # lengths in mm and E in MPa: a dimensionless image does not change
    s, e = 1e3, 1e-6
    mm = Material(E=STEEL.E * e, nu=STEEL.nu, psi=STEEL.psi)
    got = bond_image_of(small_bed.centers * s, small_bed.radii * s, mm, lo * s, hi * s,
                        (sc.cell[0] * s, sc.cell[1] * s), sc.layer_thickness * s)
    assert np.allclose(got, ref, rtol=1e-5, atol=1e-6)
    # moving the spheres and the box together by whole cells does not change it either
    shift = np.array([3 * sc.cell[0], -2 * sc.cell[1], sc.layer_thickness])
    got = bond_image_of(small_bed.centers + shift, small_bed.radii, STEEL, lo + shift,
                        hi + shift, sc.cell, sc.layer_thickness)
    assert np.allclose(got, ref, rtol=1e-4, atol=1e-5)

"""Pixelated bed images (amfe.dataset.images), checked against independent geometry.

References: sphere and spherical-cap volumes, the two-sphere lens from the cap
formula, the HCP packing fraction pi / (3 sqrt 2) of cells that are whole
lattice periods, and Monte Carlo estimates of the union (random points, a
point is filled when it lies inside any sphere). Accuracy target (docs/model.md, section 7):
about 1 % of a cell volume; the module claims about 0.1 % at its default
sampling, so the exact references are checked to 0.2 %.
"""
import math

import numpy as np
import pytest

import amfe.dataset.images as images
from amfe.dataset.images import image_box, pixelate, pixelate_spheres
from amfe.errors import AmfeError
from amfe.model.bed import Bed, generate_bed

UM = 1e-6
CELL = (30 * UM, 30 * UM)
T = 100 * UM
V_CELL = 30 * UM * 30 * UM * T
TIGHT = 2e-3      # exact references: 0.2 % of a cell
MC_TOL = 1e-2     # Monte Carlo references: the 1 % target (MC sigma ~ 0.15 %)
HCP_FRACTION = math.pi / (3.0 * math.sqrt(2.0))


def sphere_volume(r):
    return 4.0 / 3.0 * math.pi * r**3


def cap_volume(r, h):
    """Volume of a spherical cap of height h (0 <= h <= 2r) of a sphere of radius r."""
    return math.pi * h * h * (3.0 * r - h) / 3.0


def lens_volume(r1, r2, d):
    """Intersection of two spheres at distance d: two caps (|r1 - r2| < d < r1 + r2)."""
    h1 = (r2 - r1 + d) * (r2 + r1 - d) / (2.0 * d)   # cap of sphere 1 inside sphere 2
    h2 = (r1 - r2 + d) * (r1 + r2 - d) / (2.0 * d)
    return cap_volume(r1, h1) + cap_volume(r2, h2)


def one_cell_box(nx=3, ny=3, nz=2):
    return np.zeros(3), np.array([nx * 30 * UM, ny * 30 * UM, nz * T])


def mc_fraction(centers, radii, lo, hi, n, seed):
    """Monte Carlo fraction of the box [lo, hi] inside the union of the spheres (n points)."""
    rng = np.random.default_rng(seed)
    p = lo + rng.random((n, 3)) * (hi - lo)
    inside = np.zeros(n, dtype=bool)
    for c, r in zip(centers, radii):   # brute force: a few hundred spheres
        inside |= np.einsum("ij,ij->i", p - c, p - c) < r * r
    return inside.mean()


# ---------------------------------------------------------------- single spheres

@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (4.3, -6.1, 31.7)])
def test_sphere_inside_one_cell(offset):
    r = 7 * UM
    lo, hi = one_cell_box()
    # cell (layer 1, row 2, column 0): x in [0, 30], y in [60, 90], z in [100, 200] um
    c = np.array([15.0 + offset[0], 75.0 + offset[1], 150.0 + offset[2]]) * UM
    img = pixelate_spheres(c[None], [r], lo, hi, CELL, T)
    assert img.shape == (2, 3, 3) and img.dtype == np.float32
    expected = sphere_volume(r) / V_CELL          # 1.4368e-15 / 9e-14 = 0.015964
    assert abs(expected - 0.015964) < 1e-6
    assert abs(img[1, 2, 0] - expected) < TIGHT / 4   # 0.05 % of a cell
    others = np.ones(img.shape, dtype=bool)
    others[1, 2, 0] = False
    assert np.all(img[others] == 0.0)


def test_axis_conventions():
    """Layer 0 at the bottom, row index along y, column index along x, from lo."""
    lo = np.array([-50.0, 10.0, 5.0]) * UM
    hi = lo + np.array([120.0, 60.0, 300.0]) * UM       # 4 columns, 2 rows, 3 layers
    c = lo + np.array([100.0, 20.0, 250.0]) * UM         # column 3, row 0, layer 2
    img = pixelate_spheres(c[None], [5 * UM], lo, hi, CELL, T)
    assert img.shape == (3, 2, 4)
    assert np.flatnonzero(img.ravel()).tolist() == [np.ravel_multi_index((2, 0, 3), img.shape)]


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_sphere_centred_on_a_cell_face_splits_in_halves(axis):
    r = 10 * UM
    lo, hi = one_cell_box()
    c = np.array([45.0, 45.0, 50.0]) * UM
    c[axis] = (30 * UM, 30 * UM, T)[axis]                # on the face between two cells
    img = pixelate_spheres(c[None], [r], lo, hi, CELL, T).astype(float)
    # the sphere's cell is (layer 0, row 1, column 1); the other half lies one
    # cell down the axis: column 0 (x), row 0 (y), or layer 1 (z: the face is z = 100 um)
    a = (0, 1, 1)
    b = {0: (0, 1, 0), 1: (0, 0, 1), 2: (1, 1, 1)}[axis]
    half = 0.5 * sphere_volume(r) / V_CELL
    assert img[a] == pytest.approx(img[b], abs=1e-7)     # symmetric sampling
    assert abs(img[a] - half) < TIGHT / 4
    assert abs(img.sum() - 2 * half) < TIGHT / 4


@pytest.mark.parametrize("d_um", [2.0, 5.5, 9.0])
def test_sphere_straddling_a_cell_face_gives_caps(d_um):
    """Centre d from the x = 30 um face: the far side holds a cap of height r - d."""
    r, d = 12 * UM, d_um * UM
    lo, hi = one_cell_box()
    c = np.array([30 * UM - d, 47 * UM, 60 * UM])
    img = pixelate_spheres(c[None], [r], lo, hi, CELL, T).astype(float)
    cap = cap_volume(r, r - d) / V_CELL
    assert abs(img[0, 1, 1] - cap) < TIGHT / 2
    assert abs(img[0, 1, 0] - (sphere_volume(r) / V_CELL - cap)) < TIGHT / 2


# ---------------------------------------------------------------- overlaps

@pytest.mark.parametrize("r1_um, r2_um, d_um", [(14.0, 14.0, 14.0), (15.0, 10.0, 12.0)])
def test_two_overlapping_spheres_count_the_lens_once(r1_um, r2_um, d_um):
    r1, r2, d = r1_um * UM, r2_um * UM, d_um * UM
    lo, hi = one_cell_box(nx=3, ny=3, nz=1)
    direction = np.array([1.0, 0.6, 0.8]) / math.sqrt(2.0)
    mid = np.array([37.0, 34.0, 50.0]) * UM        # the pair spreads over four cells
    c = np.stack([mid - 0.5 * d * direction, mid + 0.5 * d * direction])
    img = pixelate_spheres(c, [r1, r2], lo, hi, CELL, T).astype(float)
    assert np.count_nonzero(img) == 4
    lens = lens_volume(r1, r2, d)
    union = (sphere_volume(r1) + sphere_volume(r2) - lens) / V_CELL
    assert lens / V_CELL > 5 * TIGHT          # the test can tell the union from the sum
    assert abs(img.sum() - union) < TIGHT


def test_sphere_inside_another_adds_nothing():
    lo, hi = one_cell_box(nx=1, ny=1, nz=1)
    c = np.array([[15.0, 15.0, 50.0], [17.0, 14.0, 52.0]]) * UM
    img = pixelate_spheres(c, [12 * UM, 6 * UM], lo, hi, CELL, T, spacing=2 * UM)
    single = pixelate_spheres(c[:1], [12 * UM], lo, hi, CELL, T, spacing=2 * UM)
    assert img[0, 0, 0] == pytest.approx(single[0, 0, 0], abs=1e-6)
    assert abs(single[0, 0, 0] - sphere_volume(12 * UM) / V_CELL) < TIGHT / 2


# ---------------------------------------------------------------- packed beds

def hcp_bed(r0, periods):
    """A touching HCP bed (enlargement 1, no jitter) of radius r0 and its lattice periods."""
    px, py, pz = 2 * r0, 2 * math.sqrt(3.0) * r0, 4 * math.sqrt(2.0 / 3.0) * r0
    size = (periods[0] * px, periods[1] * py, periods[2] * pz)
    bed = generate_bed(size, mean_radius=r0, enlargement=(1.0, 1.0), jitter=0.0)
    return bed, (px, py, pz)


def test_hcp_cells_of_whole_periods_read_the_packing_fraction():
    """Cells that are a whole number of lattice periods hold exactly pi / (3 sqrt 2) of spheres."""
    r0 = 10 * UM
    bed, (px, py, pz) = hcp_bed(r0, (10, 6, 5))
    img = pixelate(bed, cell=(2 * px, py), layer_thickness=pz).astype(float)
    assert img.shape == (5, 6, 5)
    interior = img[1:-1, 1:-1, 1:-1]       # the lattice is cut near the box faces
    assert np.abs(interior - HCP_FRACTION).max() < TIGHT / 2


def test_hcp_paper_cells_read_the_packing_fraction_on_average():
    """Paper cells (30 x 30 x 100 um) do not fit the lattice; their mean still does."""
    r0 = 12.5 * UM
    bed = generate_bed((360 * UM, 360 * UM, 300 * UM), mean_radius=r0,
                       enlargement=(1.0, 1.0), jitter=0.0)
    # Leave out a margin of 2 r0 at every face (the lattice is cut there).
    lo = np.full(3, 2 * r0)
    hi = lo + np.array([300 * UM, 300 * UM, 200 * UM])
    img = pixelate(bed, box=(lo, hi)).astype(float)
    assert img.shape == (2, 10, 10)
    # single cells vary by about +/- 5 % (0.71 to 0.79): they cut the lattice unevenly
    assert abs(img.mean() - HCP_FRACTION) < 0.01 * HCP_FRACTION


def test_generated_bed_pixels_converge():
    """The default sampling is within 1 % of a cell of a 4x finer one, everywhere."""
    bed = generate_bed(seed=3)
    img = pixelate(bed).astype(float)
    fine = pixelate(bed, spacing=float(np.median(bed.radii)) / 24).astype(float)
    assert img.shape == (1, 9, 9)
    assert np.abs(img - fine).max() < 0.005
    assert np.sqrt(np.mean((img - fine) ** 2)) < 0.002


def cell_volumes(img_shape, lo, hi, cell, t):
    """(layers, H, W) volumes [m^3] of the cells inside the box [lo, hi]."""
    L = np.asarray(hi) - np.asarray(lo)

    def widths(length, w, n):
        return np.minimum(w, length - w * np.arange(n))
    n_l, H, W = img_shape
    return (widths(L[2], t, n_l)[:, None, None] * widths(L[1], cell[1], H)[None, :, None]
            * widths(L[0], cell[0], W)[None, None, :])


def test_generated_bed_total_is_spheres_minus_lenses():
    """Without triple overlaps the union is sum(spheres) - sum(lenses of the bonds), exactly.

    A box around all the spheres (with partial cells) must hold that volume;
    the sum of sphere volumes is 5-6 % more.
    """
    from amfe.model.bonds import find_bonds
    bed = generate_bed(seed=3)
    bonds = find_bonds(bed.centers, bed.radii)
    lens = sum(lens_volume(bed.radii[i], bed.radii[j], d)
               for i, j, d in zip(bonds.i, bonds.j, bonds.length))
    union = bed.sphere_volume() - lens
    lo = (bed.centers - bed.radii[:, None]).min(axis=0) - 1 * UM
    hi = (bed.centers + bed.radii[:, None]).max(axis=0) + 1 * UM
    img = pixelate(bed, box=(lo, hi)).astype(float)
    assert img.shape == (2, 9, 9)
    total = float(np.sum(img * cell_volumes(img.shape, lo, hi, CELL, T)))
    assert lens > 0.05 * bed.sphere_volume()
    assert abs(total - union) < 1e-3 * union          # measured: 8e-5


# ---------------------------------------------------------------- random beds vs Monte Carlo

@pytest.fixture(scope="module")
def random_spheres():
    """150 overlapping spheres of radii 5-11 um in and around a 60 x 60 x 100 um box."""
    rng = np.random.default_rng(11)
    lo, hi = np.zeros(3), np.array([60.0, 60.0, 100.0]) * UM
    c = lo - 6 * UM + rng.random((150, 3)) * (hi - lo + 12 * UM)
    r = rng.uniform(5.0, 11.0, 150) * UM
    return c, r, lo, hi


def test_random_bed_matches_monte_carlo_per_cell(random_spheres):
    c, r, lo, hi = random_spheres
    cell, t = (30 * UM, 20 * UM), 50 * UM                 # anisotropic cells: 2 x 3 x 2
    img = pixelate_spheres(c, r, lo, hi, cell, t).astype(float)
    assert img.shape == (2, 3, 2)
    for (l, i, j), value in np.ndenumerate(img):
        clo = lo + np.array([j * cell[0], i * cell[1], l * t])
        chi = clo + np.array([cell[0], cell[1], t])
        ref = mc_fraction(c, r, clo, chi, 60_000, seed=100 + l * 10 + i * 2 + j)
        assert abs(value - ref) < MC_TOL, (l, i, j, value, ref)
    assert 0.3 < img.mean() < 0.9                         # a non-trivial test


def test_image_sum_is_the_union_volume_in_the_box(random_spheres):
    c, r, lo, hi = random_spheres
    img = pixelate_spheres(c, r, lo, hi, CELL, T).astype(float)
    assert img.shape == (1, 2, 2)
    volume = img.sum() * V_CELL
    ref = mc_fraction(c, r, lo, hi, 200_000, seed=7) * np.prod(hi - lo)
    assert abs(volume - ref) < 0.005 * np.prod(hi - lo)
    total_spheres = sum(sphere_volume(x) for x in r)
    assert volume < 0.8 * total_spheres                    # overlaps counted once


def test_strips_and_chunks_do_not_change_the_result(random_spheres, monkeypatch):
    c, r, lo, hi = random_spheres
    ref = pixelate_spheres(c, r, lo, hi, (20 * UM, 15 * UM), 30 * UM)
    monkeypatch.setattr(images, "_TILE_CHORDS", 500)
    monkeypatch.setattr(images, "_CHUNK_CANDIDATES", 300)
    small = pixelate_spheres(c, r, lo, hi, (20 * UM, 15 * UM), 30 * UM)
    np.testing.assert_allclose(small, ref, atol=1e-6)


# ---------------------------------------------------------------- ranges and boxes

def test_empty_region_is_exactly_zero_and_range():
    bed = generate_bed((150 * UM, 150 * UM, 100 * UM), seed=1)
    lo, hi = np.zeros(3), np.array([300.0, 150.0, 200.0]) * UM   # the bed fills the lower left
    img = pixelate(bed, box=(lo, hi))
    assert img.shape == (2, 5, 10)
    assert np.all(img[1] == 0.0) and np.all(img[:, :, 6:] == 0.0)
    assert img.min() >= 0.0 and img.max() <= 1.0
    assert img[0, 1:4, 1:4].min() > 0.5


def test_full_cells_read_one_and_partial_cells_are_relative_to_the_box():
    """Box 0.25 mm wide: 9 columns of 0.03 mm, the last 0.01 mm wide (inside the box)."""
    lo, hi = np.zeros(3), np.array([250.0, 90.0, 100.0]) * UM
    big = np.array([[125.0, 45.0, 50.0]]) * UM
    img = pixelate_spheres(big, [1e-3], lo, hi, CELL, T)
    assert img.shape == (1, 3, 9)
    assert np.all(img == 1.0)                         # the partial column too
    # A half space x < 245 um (a sphere of radius 1 m): the last column is
    # [240, 250] um, half filled: 0.5 relative to its part in the box.
    R = 1.0
    plane = np.array([[245 * UM - R, 45 * UM, 50 * UM]])
    img = pixelate_spheres(plane, [R], lo, hi, CELL, T, spacing=1 * UM).astype(float)
    assert np.allclose(img[..., :8], 1.0, atol=1e-6)
    assert img[..., 8] == pytest.approx(0.5, abs=1e-3)


def test_layers_partial_and_layer_thickness_from_attrs():
    bed = generate_bed((150 * UM, 150 * UM, 150 * UM), seed=2, layer_thickness=50 * UM)
    img = pixelate(bed)
    assert img.shape == (3, 5, 5)                     # layer thickness from attrs
    img = pixelate(bed, layer_thickness=100 * UM)
    assert img.shape == (2, 5, 5)                     # the top layer is 50 um of 100
    no_attrs = Bed(bed.centers, bed.radii)
    lo, hi = image_box(no_attrs)
    assert np.allclose(lo, (bed.centers - bed.radii[:, None]).min(axis=0))
    assert np.allclose(hi, (bed.centers + bed.radii[:, None]).max(axis=0))
    assert pixelate(no_attrs).shape[0] == math.ceil((hi[2] - lo[2]) / 100e-6)


def test_paper_shape():
    """A 3 mm x 3 mm x 0.3 mm box is a 3 x 100 x 100 image (a few spheres suffice)."""
    bed = Bed(np.array([[1.5e-3, 1.5e-3, 0.1e-3]]), [20 * UM], {"size": [3e-3, 3e-3, 0.3e-3]})
    img = pixelate(bed)
    assert img.shape == (3, 100, 100)
    assert np.count_nonzero(img) == 4 * 2              # on a cell corner and a layer face
    assert np.flatnonzero(img.sum(axis=(1, 2))).tolist() == [0, 1]


# ---------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs", [
    {"cell": (0.0, 30e-6)},
    {"cell": (30e-6, -1e-6)},
    {"cell": (30e-6,)},
    {"cell": ("a", 30e-6)},
    {"layer_thickness": 0.0},
    {"layer_thickness": float("nan")},
    {"box": (np.zeros(3), np.array([1e-4, 1e-4, 0.0]))},
    {"box": (np.ones(3) * 1e-4, np.zeros(3))},
    {"box": (np.zeros(3), np.array([1e-4, np.inf, 1e-4]))},
    {"box": np.zeros(3)},
    {"spacing": 0.0},
])
def test_bad_input_raises(kwargs):
    bed = Bed(np.array([[5e-5, 5e-5, 5e-5]]), [1e-5], {"size": [1e-4, 1e-4, 1e-4]})
    with pytest.raises(AmfeError):
        pixelate(bed, **kwargs)


def test_bad_particles_raise():
    lo, hi = np.zeros(3), np.ones(3) * 1e-4
    with pytest.raises(AmfeError):
        pixelate_spheres(np.empty((0, 3)), np.empty(0), lo, hi)
    with pytest.raises(AmfeError):
        pixelate_spheres(np.zeros((1, 3)), [0.0], lo, hi)
    with pytest.raises(AmfeError):
        pixelate(object())

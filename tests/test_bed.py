"""HCP bed generator and scan paths, checked against independent geometry.

References: the close-packed lattice (12 neighbours at 2 r0, volume 4 sqrt(2) r0^3
per sphere, packing fraction pi / (3 sqrt 2)), the a* of a pair from the
textbook form a = sqrt(R_i^2 - d_i^2), and hatch membership from modular
arithmetic rather than the module's nearest-line search.
"""
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from amfe.errors import AmfeError
from amfe.model.bed import Bed, generate_bed, hcp_lattice, limit_a_star, pair_a_star, shrink_factor
from amfe.model.bonds import find_bonds
from amfe.model.material import STEEL, Material
from amfe.model.scanpath import ScanPath, scanned_mask
from amfe.model.springs import critical_a_star

CRIT = critical_a_star(STEEL.nu, STEEL.psi)
SMALL = (150e-6, 150e-6, 100e-6)   # a few hundred particles


def a_star_textbook(L, Ri, Rj):
    """a* from d_i and a = sqrt(R_i^2 - d_i^2) (independent of the Heron form)."""
    d_i = (L**2 + Ri**2 - Rj**2) / (2 * L)
    return np.sqrt(Ri**2 - d_i**2) * (Ri + Rj) / (Ri * Rj)


# --------------------------------------------------------------------------- #
# Determinism
# --------------------------------------------------------------------------- #
def test_same_seed_same_bed_bit_for_bit():
    scan = ScanPath(track_width=60e-6, hatch_spacing=80e-6, angle=30, skip_fraction=0.3,
                    skip_length=40e-6)
    a = generate_bed(SMALL, seed=7, scan=scan)
    b = generate_bed(SMALL, seed=7, scan=scan)
    assert np.array_equal(a.centers, b.centers)
    assert np.array_equal(a.radii, b.radii)
    assert a.attrs == b.attrs


def test_different_seed_different_bed():
    a = generate_bed(SMALL, seed=1)
    b = generate_bed(SMALL, seed=2)
    assert a.n == b.n  # same lattice, fully scanned
    assert not np.array_equal(a.radii, b.radii)
    assert not np.array_equal(a.centers, b.centers)


def test_attrs_record_the_parameters():
    scan = ScanPath(track_width=60e-6, hatch_spacing=80e-6, angle=10, layer_rotation=90)
    bed = generate_bed(SMALL, seed=4, enlargement=(1.06, 1.12), jitter=0.02, scan=scan,
                       a_star_max=0.97)
    at = bed.attrs
    assert at["generator"] == "amfe.hcp"
    assert at["size"] == list(SMALL)
    assert at["seed"] == 4
    assert at["enlargement"] == [1.06, 1.12]
    assert at["jitter"] == 0.02
    assert at["r0"] == pytest.approx(12.5e-6 / 1.09)
    assert at["scan"] == "raster" and at["scan_layer_rotation"] == 90.0
    assert at["scan_track_width"] == 60e-6
    assert at["material_E"] == 210e9 and at["material_nu"] == 0.28
    assert at["material_psi"] == 0.08 and at["material_density"] == 7800.0
    assert at["a_star_max"] == 0.97
    assert at["n_lattice"] - at["n_scanned_out"] == bed.n
    assert isinstance(at["n_shrunk"], int)
    assert bed.material() == STEEL
    assert generate_bed(SMALL).attrs["scan"] == "full"


def test_mean_radius_is_the_target_before_shrinking():
    bed = generate_bed((400e-6, 400e-6, 200e-6), seed=0, enlargement=(1.05, 1.10),
                       a_star_max=0.99)
    assert bed.attrs["n_shrunk"] == 0
    # Uniform factors in [1.05, 1.10] around r0 = 12.5 um / 1.075: mean 12.5 um
    # within the sampling error (std of the mean ~ 0.0144 r0 / sqrt(N)).
    assert bed.radii.mean() == pytest.approx(12.5e-6, rel=3e-3)
    assert bed.radii.min() >= 12.5e-6 / 1.075 * 1.05 * (1 - 1e-15)
    assert bed.radii.max() <= 12.5e-6 / 1.075 * 1.10 * (1 + 1e-15)


def test_jitter_is_uniform_within_jitter_times_own_radius():
    size = (300e-6, 300e-6, 150e-6)
    bed = generate_bed(size, seed=3, enlargement=(1.05, 1.10), jitter=0.025, a_star_max=0.99)
    assert bed.attrs["n_shrunk"] == 0
    lattice = hcp_lattice(size, bed.attrs["r0"])
    assert lattice.shape == bed.centers.shape
    u = (bed.centers - lattice) / (0.025 * bed.radii[:, None])   # U(-1, 1) per axis
    assert np.abs(u).max() <= 1.0 + 1e-9
    assert np.abs(u).max() > 0.99           # scaled by R_i, not by r0 (R_i / r0 >= 1.05)
    assert np.abs(u).mean() == pytest.approx(0.5, abs=0.03)
    assert np.abs(np.corrcoef(u.T) - np.eye(3)).max() < 0.1   # axes independent


# --------------------------------------------------------------------------- #
# The lattice
# --------------------------------------------------------------------------- #
def test_close_packed_count_and_packing_fraction():
    """A box of whole lattice periods holds nx*ny*nz spheres at density pi/(3 sqrt 2)."""
    r0 = 1.0
    h = 2 * r0 * math.sqrt(2 / 3)
    nx, ny, nz, slack = 8, 7, 6, 0.3 * r0
    # Rows alternate x offsets 0 and r0, B layers are shifted (r0, r0/sqrt 3):
    # these sizes give every row nx sites, every layer ny rows, nz layers.
    size = (2 * r0 + 2 * r0 * (nx - 1) + r0 + slack,
            2 * r0 + math.sqrt(3) * r0 * (ny - 1) + r0 / math.sqrt(3) + slack,
            2 * r0 + h * (nz - 1) + slack)
    bed = generate_bed(size, mean_radius=r0, enlargement=(1.0, 1.0), jitter=0.0)
    assert np.all(bed.radii == r0)
    assert bed.n == nx * ny * nz
    # Volume per sphere of a close packing is 4 sqrt(2) r0^3; the lattice region
    # of nx x ny x nz cells has volume (2 r0 nx)(sqrt(3) r0 ny)(h nz).
    cell_volume = (2 * r0 * nx) * (math.sqrt(3) * r0 * ny) * (h * nz)
    assert cell_volume / bed.n == pytest.approx(4 * math.sqrt(2) * r0**3, rel=1e-12)
    phi = bed.n * 4 / 3 * math.pi * r0**3 / cell_volume
    assert phi == pytest.approx(math.pi / (3 * math.sqrt(2)), rel=1e-12)
    assert phi == pytest.approx(0.7405, abs=1e-4)
    # Close packing: no two spheres closer than 2 r0, interior ones touch 12.
    tree = cKDTree(bed.centers)
    d, _ = tree.query(bed.centers, k=14)
    assert d[:, 1].min() == pytest.approx(2 * r0, rel=1e-12)
    lo, hi = bed.centers.min(axis=0), bed.centers.max(axis=0)
    interior = np.all((bed.centers > lo + 2.5 * r0) & (bed.centers < hi - 2.5 * r0), axis=1)
    assert interior.sum() > 10
    assert np.allclose(d[interior, 1:13], 2 * r0, rtol=1e-12)
    assert np.all(d[interior, 13] > 2.8 * r0)  # next shell at 2 sqrt(2) r0


def test_large_box_number_density():
    """Count in a box that is not a whole number of periods: edge effect bounded."""
    r0 = 1.0
    size = (60.0, 50.0, 40.0)
    n = hcp_lattice(size, r0).shape[0]
    # Centres fill [r0, L - r0]; each site owns a cell of 4 sqrt(2) r0^3 whose
    # extent is 2r0 x sqrt(3) r0 x h, so the count lies between the cells that fit
    # in the shrunk region and those that fit in it grown by one cell per axis.
    h = 2 * r0 * math.sqrt(2 / 3)
    inner = np.array(size) - 2 * r0
    cell = np.array([2 * r0, math.sqrt(3) * r0, h])
    lower = np.prod(inner - cell) / (4 * math.sqrt(2) * r0**3)
    upper = np.prod(inner + cell) / (4 * math.sqrt(2) * r0**3)
    assert lower < n < upper


def test_abab_stacking():
    r0 = 1.0
    pts = hcp_lattice((20, 20, 10), r0)
    z = np.unique(np.round(pts[:, 2], 9))
    layers = [pts[np.isclose(pts[:, 2], zz)][:, :2] for zz in z[:3]]
    assert z[1] - z[0] == pytest.approx(2 * r0 * math.sqrt(2 / 3))
    # Layer C sits straight over layer A (hcp, not fcc), layer B does not.
    key = lambda xy: set(map(tuple, np.round(xy, 9)))  # noqa: E731
    assert key(layers[0]) == key(layers[2])
    assert not key(layers[0]) & key(layers[1])
    # B sites lie over the centres of A triangles: distance r0 * 2/sqrt(3) in-plane.
    d, _ = cKDTree(layers[0]).query(layers[1])
    assert np.allclose(d, 2 * r0 / math.sqrt(3))


def test_interior_particles_of_enlarged_bed_have_twelve_bonds():
    r0 = 10e-6
    bed = generate_bed((200e-6, 200e-6, 150e-6), mean_radius=1.1 * r0, enlargement=(1.1, 1.1),
                       jitter=0.0, a_star_max=0.95)
    assert bed.attrs["n_shrunk"] == 0
    bonds = find_bonds(bed.centers, bed.radii)
    count = np.bincount(bonds.i, minlength=bed.n) + np.bincount(bonds.j, minlength=bed.n)
    lo, hi = bed.centers.min(axis=0), bed.centers.max(axis=0)
    interior = np.all((bed.centers > lo + 2.5 * r0) & (bed.centers < hi - 2.5 * r0), axis=1)
    assert interior.sum() > 20
    assert np.all(count[interior] == 12)
    assert np.all(count <= 12)
    assert np.allclose(bonds.length, 2 * r0, rtol=1e-12)
    # Equal spheres of radius 1.1 r0 at 2 r0: a = r0 sqrt(0.21), R_eff = 0.55 r0.
    assert np.allclose(bonds.a_star, math.sqrt(0.21) / 0.55, rtol=1e-12)


def test_touching_spheres_are_not_bonded():
    r0 = 1.0
    bed = generate_bed((9.0, 9.0, 9.0), mean_radius=r0, enlargement=(1.0, 1.0), jitter=0.0)
    bonds = find_bonds(bed.centers, bed.radii)
    # Contacts at L = 2 r0 exactly are no bonds; round-off may leave a few with
    # an overlap of an ulp, whose a* is ~1e-7 and harmless.
    assert np.all(bonds.a_star < 1e-6)


# --------------------------------------------------------------------------- #
# The a* guarantee
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_every_bond_valid_with_paper_enlargement(seed):
    bed = generate_bed(SMALL, seed=seed, enlargement=(1.05, 1.14))
    bonds = find_bonds(bed.centers, bed.radii)
    assert bonds.a_star.max() <= 0.98 < CRIT
    # Independent a*: textbook contact radius.
    s = a_star_textbook(bonds.length, bed.radii[bonds.i], bed.radii[bonds.j])
    assert s.max() <= 0.98 + 1e-9
    # n_shrunk counts the radii below their drawn value (same rng, same order).
    at = bed.attrs
    n = at["n_lattice"]
    drawn = at["r0"] * np.random.default_rng(seed).uniform(1.05, 1.14, n)
    assert n == bed.n  # fully scanned
    assert np.all(bed.radii <= drawn)
    assert at["n_shrunk"] == int(np.sum(bed.radii < drawn))
    # Shrinking is small: a few per cent at most.
    assert np.all(bed.radii >= 0.95 * drawn)


def test_paper_enlargement_needs_shrinking_at_all():
    """Without the rule the paper's range gives bonds past the critical a*."""
    shrunk = [generate_bed(SMALL, seed=s).attrs["n_shrunk"] for s in range(4)]
    assert all(k > 0 for k in shrunk)
    bed = generate_bed(SMALL, seed=0)
    drawn = bed.attrs["r0"] * np.random.default_rng(0).uniform(1.05, 1.14, bed.n)
    raw = find_bonds(bed.centers, drawn)
    assert raw.a_star.max() > 0.98


def test_tighter_a_star_max():
    bed = generate_bed(SMALL, seed=3, a_star_max=0.9)
    assert find_bonds(bed.centers, bed.radii).a_star.max() <= 0.9
    assert bed.attrs["n_shrunk"] > generate_bed(SMALL, seed=3).attrs["n_shrunk"]


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_enlargement_up_to_1_10_needs_no_shrinking(seed):
    # Worst case: both radii 1.10 r0 and jitter pushing the pair together along
    # the neighbour direction with the largest 1-norm (inter-layer, 1.6052).
    e = np.array([1.0, 1 / math.sqrt(3), 2 * math.sqrt(2 / 3)]) / 2  # |e| = 1
    assert np.linalg.norm(e) == pytest.approx(1.0)
    L = 2 - 2 * 0.025 * 1.10 * np.abs(e).sum()
    worst = a_star_textbook(L, 1.10, 1.10)
    assert 0.98 < worst < 0.99 < CRIT
    bed = generate_bed(SMALL, seed=seed, enlargement=(1.05, 1.10), a_star_max=0.99)
    assert bed.attrs["n_shrunk"] == 0
    assert find_bonds(bed.centers, bed.radii).a_star.max() < worst


def test_a_star_max_must_be_below_critical():
    with pytest.raises(AmfeError, match="critical"):
        generate_bed(SMALL, a_star_max=CRIT)
    with pytest.raises(AmfeError, match="a\\* max"):
        generate_bed(SMALL, a_star_max=0.0)
    # The critical value follows the material.
    soft = Material(nu=0.28, psi=0.2)
    with pytest.raises(AmfeError, match="critical"):
        generate_bed(SMALL, a_star_max=0.98, material=soft)


def test_a_star_increases_with_common_factor():
    """a*(lam) with both radii scaled by lam at fixed L is monotone (the bisection needs it)."""
    rng = np.random.default_rng(0)
    Ri = rng.uniform(0.9, 1.2, 2000)
    Rj = rng.uniform(0.9, 1.2, 2000)
    L = rng.uniform(0.85, 0.999, 2000) * (Ri + Rj)
    lo = L / (Ri + Rj)                                     # a* = 0: just touching
    lam = np.linspace(lo + 0.01 * (1 - lo), 1.0, 200)     # (200, M)
    s = a_star_textbook(L, lam * Ri, lam * Rj)
    assert np.all(np.isfinite(s))
    assert np.all(np.diff(s, axis=0) > 0)


def test_a_star_increases_with_each_radius():
    """Shrinking one particle lowers the a* of its other bonds (for a* < 1.3)."""
    rng = np.random.default_rng(1)
    Ri = rng.uniform(0.85, 1.2, 20000)
    Rj = rng.uniform(0.85, 1.2, 20000)
    L = rng.uniform(0.8, 0.999, 20000) * (Ri + Rj)
    s0 = a_star_textbook(L, Ri, Rj)
    keep = (s0 < 1.3) & ((L**2 + Ri**2 - Rj**2) > 0) & ((L**2 + Rj**2 - Ri**2) > 0)
    for f in (0.999, 0.99, 0.97):
        with np.errstate(invalid="ignore"):  # pairs that no longer overlap: NaN, filtered
            s1 = a_star_textbook(L, f * Ri, Rj)
        ok = keep & (f * Ri + Rj > L)
        assert np.all(s1[ok] < s0[ok])


def test_shrink_factor_hits_target():
    rng = np.random.default_rng(2)
    Ri = rng.uniform(1.0, 1.2, 500)
    Rj = rng.uniform(1.0, 1.2, 500)
    L = rng.uniform(0.85, 0.95, 500) * (Ri + Rj)
    target = 0.9
    above = pair_a_star(L, Ri, Rj) > target
    assert above.sum() > 100
    L, Ri, Rj = L[above], Ri[above], Rj[above]
    lam = shrink_factor(L, Ri, Rj, target)
    s = pair_a_star(L, lam * Ri, lam * Rj)
    assert np.all(s <= target)
    assert np.allclose(a_star_textbook(L, lam * Ri, lam * Rj), target, rtol=1e-9)
    assert np.all((lam < 1) & (lam > L / (Ri + Rj)))


def test_limit_a_star_smallest_factor_wins():
    # A chain 0-1-2 along x: bond 0-1 overlaps more than bond 1-2, both past 0.98.
    R = np.array([1.14, 1.14, 1.14])
    x = np.array([[0.0, 0, 0], [1.92, 0, 0], [1.92 + 1.95, 0, 0]])
    before = find_bonds(x, R).a_star
    assert np.all(before > 0.98)
    radii, n_shrunk, passes = limit_a_star(x, R, 0.98)
    after = find_bonds(x, radii)
    assert n_shrunk == 3 and passes == 1
    assert after.a_star[0] == pytest.approx(0.98, rel=1e-12)   # the tighter pair: exactly a*_max
    assert after.a_star[1] < 0.98                                # the looser one: below
    assert radii[0] == radii[1] < radii[2] < 1.14
    lam01 = shrink_factor(np.array([1.92]), R[:1], R[1:2], 0.98)[0]
    assert radii[1] == 1.14 * lam01


def test_limit_a_star_leaves_valid_beds_alone():
    x = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    r = np.array([1.05, 1.05])
    radii, n_shrunk, passes = limit_a_star(x, r, 0.98)
    assert n_shrunk == 0 and passes == 0 and np.array_equal(radii, r)


# --------------------------------------------------------------------------- #
# Input validation
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("kw, match", [
    ({"size": (-1e-4, 1e-4, 1e-4)}, "size"),
    ({"size": (1e-4, 1e-4)}, "size"),
    ({"size": (1e-4, np.nan, 1e-4)}, "size"),
    ({"enlargement": (1.14, 1.05)}, "enlargement"),
    ({"enlargement": (0.9, 1.05)}, "enlargement"),
    ({"enlargement": (1.05, 1.5)}, "enlargement"),
    ({"jitter": -0.1}, "jitter"),
    ({"jitter": 0.6}, "jitter"),
    ({"mean_radius": 0.0}, "mean radius"),
    ({"seed": -1}, "seed"),
    ({"seed": 1.5}, "seed"),
    ({"layer_thickness": 0.0}, "layer thickness"),
    ({"size": (10e-6, 1e-4, 1e-4)}, "holds no particle"),
])
def test_bad_arguments(kw, match):
    args = {"size": SMALL, **kw}
    size = args.pop("size")
    with pytest.raises(AmfeError, match=match):
        generate_bed(size, **args)


def test_bed_container_validates():
    with pytest.raises(AmfeError, match="shape"):
        Bed(np.zeros((3, 2)), np.ones(3))
    with pytest.raises(AmfeError, match="non-positive"):
        Bed(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], np.array([1.0, -1.0]))
    b = Bed([[0, 0, 0]], [1.0])
    assert b.centers.dtype == np.float64 and b.centers.shape == (1, 3) and len(b) == 1
    assert b.sphere_volume() == pytest.approx(4 / 3 * math.pi)
    assert b.material() is STEEL


# --------------------------------------------------------------------------- #
# Scan paths
# --------------------------------------------------------------------------- #
def on_hatch(coord, w, h, off):
    """Within w/2 of a line at off + k h (k integer): modular, independent of the module."""
    r = np.mod(coord - off, h)
    return (r <= w / 2) | (r >= h - w / 2)


def random_centers(n, size, seed=0):
    return np.random.default_rng(seed).uniform(0, 1, (n, 3)) * np.array(size)


def test_hatch_angle_0_keeps_y_strips():
    size = (1e-3, 1e-3, 0.1e-3)
    x = random_centers(20000, size)
    w, h, off = 60e-6, 100e-6, 17e-6
    scan = ScanPath(track_width=w, hatch_spacing=h, angle=0.0, offset=off)
    keep = scanned_mask(x, size, 0.1e-3, scan, np.random.default_rng(0))
    assert np.array_equal(keep, on_hatch(x[:, 1], w, h, off))
    assert keep.mean() == pytest.approx(w / h, abs=0.02)


def test_hatch_angle_90_keeps_x_strips():
    size = (1e-3, 1e-3, 0.1e-3)
    x = random_centers(20000, size, seed=1)
    w, h, off = 40e-6, 90e-6, 25e-6
    scan = ScanPath(track_width=w, hatch_spacing=h, angle=90.0, offset=off)
    keep = scanned_mask(x, size, 0.1e-3, scan)
    # Normal (-sin, cos) = (-1, 0): lines at -x = off + k h.
    assert np.array_equal(keep, on_hatch(-x[:, 0], w, h, off))
    assert not np.array_equal(keep, on_hatch(x[:, 1], w, h, off))


def test_hatch_oblique_angle():
    size = (1e-3, 1e-3, 0.1e-3)
    x = random_centers(20000, size, seed=2)
    w, h = 50e-6, 120e-6
    scan = ScanPath(track_width=w, hatch_spacing=h, angle=45.0)
    keep = scanned_mask(x, size, 0.1e-3, scan)
    # Tracks along (1, 1)/sqrt 2: distance coordinate (y - x)/sqrt 2.
    assert np.array_equal(keep, on_hatch((x[:, 1] - x[:, 0]) / math.sqrt(2), w, h, 0.0))


def test_layer_rotation_applies_to_second_layer():
    size = (1e-3, 1e-3, 0.2e-3)
    t = 0.1e-3
    x = random_centers(30000, size, seed=3)
    w, h = 50e-6, 100e-6
    scan = ScanPath(track_width=w, hatch_spacing=h, angle=0.0, layer_rotation=90.0)
    keep = scanned_mask(x, size, t, scan)
    first = x[:, 2] < t
    assert first.sum() > 1000 and (~first).sum() > 1000
    assert np.array_equal(keep[first], on_hatch(x[first, 1], w, h, 0.0))
    assert np.array_equal(keep[~first], on_hatch(-x[~first, 0], w, h, 0.0))


def test_overlapping_tracks_and_full_path_keep_everything():
    size = (1e-3, 1e-3, 0.2e-3)
    x = random_centers(5000, size, seed=4)
    rng = np.random.default_rng(0)
    for scan in (None, ScanPath.full(), ScanPath(track_width=80e-6, hatch_spacing=50e-6)):
        assert scanned_mask(x, size, 0.1e-3, scan, rng).all()


def test_skipped_segments():
    size = (2e-3, 2e-3, 0.1e-3)
    x = random_centers(40000, size, seed=5)
    base = ScanPath(track_width=60e-6, hatch_spacing=100e-6, angle=30, skip_length=100e-6)
    no_skip = scanned_mask(x, size, 0.1e-3, base)
    rng = np.random.default_rng(9)
    state = rng.bit_generator.state
    zero = ScanPath(**{**base.__dict__, "skip_fraction": 0.0})
    assert np.array_equal(scanned_mask(x, size, 0.1e-3, zero, rng), no_skip)
    assert rng.bit_generator.state == state  # nothing drawn
    half = ScanPath(**{**base.__dict__, "skip_fraction": 0.4})
    keep = scanned_mask(x, size, 0.1e-3, half, np.random.default_rng(9))
    assert np.all(keep <= no_skip) and keep.sum() < no_skip.sum()
    assert 1 - keep.sum() / no_skip.sum() == pytest.approx(0.4, abs=0.06)
    # Whole pieces are skipped: group the on-track points by (track, piece).
    th = math.radians(30)
    v = -math.sin(th) * x[:, 0] + math.cos(th) * x[:, 1]
    u = math.cos(th) * x[:, 0] + math.sin(th) * x[:, 1]
    k = np.rint(v / 100e-6).astype(int)
    m = np.floor(u / 100e-6).astype(int)
    sel = np.flatnonzero(no_skip)
    groups = {}
    for idx in sel:
        groups.setdefault((k[idx], m[idx]), set()).add(bool(keep[idx]))
    assert all(len(g) == 1 for g in groups.values())
    assert sum(g == {False} for g in groups.values()) > 10
    # Same rng seed -> same mask; another seed -> another mask.
    assert np.array_equal(keep, scanned_mask(x, size, 0.1e-3, half, np.random.default_rng(9)))
    assert not np.array_equal(keep, scanned_mask(x, size, 0.1e-3, half, np.random.default_rng(8)))


def test_generated_bed_follows_scan_path():
    size = (300e-6, 300e-6, 100e-6)
    w, h = 50e-6, 90e-6
    scan = ScanPath(track_width=w, hatch_spacing=h, angle=0.0, offset=20e-6)
    full = generate_bed(size, seed=2)
    bed = generate_bed(size, seed=2, scan=scan)
    assert 0 < bed.n < full.n
    assert bed.attrs["n_scanned_out"] == full.n - bed.n
    assert np.all(on_hatch(bed.centers[:, 1], w, h, 20e-6))
    # The kept particles are the fully scanned bed's, at the same place (the
    # scan draws after the jitter; radii may differ only by the a* shrinking).
    tree = cKDTree(full.centers)
    d, _ = tree.query(bed.centers)
    assert np.all(d == 0)


def test_scan_path_deleting_everything_is_an_error():
    scan = ScanPath(track_width=1e-6, hatch_spacing=10e-3, offset=5e-3)
    with pytest.raises(AmfeError, match="deletes every particle"):
        generate_bed(SMALL, scan=scan)


@pytest.mark.parametrize("kw, match", [
    ({"track_width": 0.0}, "track width"),
    ({"track_width": -1e-6}, "track width"),
    ({"hatch_spacing": 0.0}, "hatch spacing"),
    ({"skip_fraction": 1.0}, "skip fraction"),
    ({"skip_fraction": -0.1}, "skip fraction"),
    ({"skip_length": 0.0}, "skip length"),
    ({"angle": float("nan")}, "angle"),
    ({"offset": float("inf")}, "offset"),
])
def test_scan_path_validation(kw, match):
    args = {"track_width": 50e-6, "hatch_spacing": 100e-6, **kw}
    with pytest.raises(AmfeError, match=match):
        ScanPath(**args)


def test_skipping_without_rng_is_an_error():
    scan = ScanPath(track_width=50e-6, hatch_spacing=100e-6, skip_fraction=0.2)
    with pytest.raises(AmfeError, match="rng"):
        scanned_mask(np.zeros((2, 3)), (1e-3, 1e-3, 1e-3), 1e-4, scan)


def test_skip_seed_holds_the_holes_and_is_opt_in():
    from amfe.model.scanpath import ScanPath
    scan = ScanPath(track_width=0.1e-3, hatch_spacing=0.1e-3, skip_fraction=0.4,
                    skip_length=0.08e-3)
    kw = dict(size=(0.3e-3, 0.3e-3, 0.1e-3), scan=scan)
    # Without skip_seed nothing changes: the same bed bit for bit.
    a, b = generate_bed(**kw, seed=4), generate_bed(**kw, seed=4, skip_seed=None)
    assert np.array_equal(a.centers, b.centers) and np.array_equal(a.radii, b.radii)
    assert "skip_seed" not in b.attrs
    # Fixed enlargement and no jitter: centres and radii do not depend on the seed,
    # so only the skipped pieces can differ between two seeds.
    fixed = dict(kw, enlargement=(1.08, 1.08), jitter=0.0)
    one, two = generate_bed(**fixed, seed=1), generate_bed(**fixed, seed=2)
    assert not np.array_equal(one.centers, two.centers)        # the holes moved
    one, two = (generate_bed(**fixed, seed=s, skip_seed=9) for s in (1, 2))
    assert np.array_equal(one.centers, two.centers) and one.attrs["skip_seed"] == 9
    with pytest.raises(AmfeError, match="skip_seed"):
        generate_bed(**kw, skip_seed=-1)

"""The solid fraction (amfe.dataset.density) against Monte Carlo and against exact volumes."""
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from amfe.dataset.density import PRECISION, solid_fraction
from amfe.model.scales import bed_for

MC_POINTS = 10**7


def monte_carlo(centers, radii, lo, hi, n=MC_POINTS, seed=0):
    """(fraction, standard error) of n uniform points of the box inside some sphere."""
    rng = np.random.default_rng(seed)
    tree = cKDTree(centers)
    reach = float(radii.max())
    hits = 0
    for _ in range(10):
        p = lo + rng.random((n // 10, 3)) * (hi - lo)
        d, i = tree.query(p, k=8, distance_upper_bound=reach, workers=2)
        found = np.isfinite(d)
        r = np.where(found, radii[np.minimum(i, len(radii) - 1)], -1.0)
        hits += int(np.count_nonzero(np.any(d <= r, axis=1)))
    f = hits / n
    return f, math.sqrt(f * (1 - f) / n)


@pytest.mark.parametrize("scale,seed", [("small", 11), ("small", 12), ("tiny", 3)])
def test_within_its_stated_precision_of_monte_carlo(scale, seed):
    bed = bed_for(scale, seed)
    lo, hi = np.zeros(3), np.asarray(bed.attrs["size"], dtype=float)
    f, err = solid_fraction(bed.centers, bed.radii, lo, hi)
    assert err <= PRECISION / 2
    mc, se = monte_carlo(bed.centers, bed.radii, lo, hi)
    assert se < 2e-4
    assert abs(f - mc) <= PRECISION, (f, mc, se)


def test_overlapping_pair_counts_the_lens_once():
    """Two unit spheres at distance d: 2 V - lens, the lens pi (4 + d)(2 - d)^2 / 12."""
    d = 1.2
    c = np.array([[0.0, 0.0, 0.0], [d, 0.0, 0.0]])
    r = np.ones(2)
    lo, hi = np.array([-1.5, -1.5, -1.5]), np.array([d + 1.5, 1.5, 1.5])
    union = 2 * 4 / 3 * math.pi - math.pi * (4 + d) * (2 - d) ** 2 / 12
    exact = union / float(np.prod(hi - lo))
    f, err = solid_fraction(c, r, lo, hi)
    assert abs(f - exact) <= PRECISION and err <= PRECISION / 2


def test_only_the_part_inside_the_box_counts():
    """A sphere cut in half by the box's floor: half its volume."""
    c, r = np.zeros((1, 3)), np.ones(1)
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0])
    f, err = solid_fraction(c, r, lo, hi)
    assert abs(f - (2 / 3 * math.pi) / 4.0) <= PRECISION and err <= PRECISION / 2


def test_a_bad_box_is_refused():
    from amfe.errors import AmfeError
    with pytest.raises(AmfeError, match="box"):
        solid_fraction(np.zeros((1, 3)), np.ones(1), np.ones(3), np.zeros(3))

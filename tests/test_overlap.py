"""Roberts and Garboczi's overlapping-sphere cells (docs/model.md, section 10)."""
import math

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.model.overlap import expected_count, overlapping_spheres


def void_share(centers, radii, cell, points):
    """Share of points (k, 3) outside every sphere, distances by minimum image."""
    d = points[:, None, :] - centers[None, :, :]
    d -= cell * np.round(d / cell)
    return float(np.mean(np.all(np.einsum("pnk,pnk->pn", d, d) >= radii ** 2, axis=1)))


@pytest.mark.parametrize("porosity", [0.3, 0.5])
def test_the_cells_porosity_is_the_target_on_average(porosity):
    r, cell = 1.0, 5.0
    v = 4.0 / 3.0 * math.pi * r ** 3
    rng = np.random.default_rng(7)
    shares = []
    for seed in range(24):
        x, radii = overlapping_spheres(porosity, r, cell, seed=seed)
        assert len(radii) == round(-math.log(porosity) * cell ** 3 / v)
        assert np.all(radii == r) and np.all((x >= 0) & (x < cell))
        shares.append(void_share(x, radii, cell, rng.uniform(0, cell, size=(1500, 3))))
    expected = (1.0 - v / cell ** 3) ** len(radii)        # binomial point process
    assert abs(expected - porosity) < 0.02     # rounding N and the binomial correction
    # spread of the cells' porosity and of 1500 points: 24 cells give the mean to ~0.01
    assert abs(np.mean(shares) - expected) < 4 * np.std(shares) / math.sqrt(len(shares)) + 0.005
    assert np.std(shares) > 0        # the cells differ: the centres are random


def test_overlapping_spheres_rejects_bad_input():
    with pytest.raises(AmfeError, match="porosity"):
        expected_count(1.2, 1.0, 5.0)
    with pytest.raises(AmfeError, match="positive"):
        expected_count(0.5, -1.0, 5.0)

"""Roberts and Garboczi's overlapping solid spheres: a periodic cell, pure numpy.

docs/model.md, section 10 ("Roberts and Garboczi's cells"). Centres are
uniform and independent in the period box (a binomial point process, so spheres
overlap freely, unlike a sintered bed); at number density n the porosity
of the union of spheres of radius r is (1 - v / V)^N -> exp(-n v), v = 4/3 pi r^3
(Torquato, Random Heterogeneous Materials, 2002, section 3.1). The cell is periodic: a
sphere near a face is continued across it by the periodic voxelisation.
"""
import math

import numpy as np

from amfe.errors import AmfeError


def expected_count(porosity, radius, cell):
    """Mean number of spheres, -ln(porosity) V / (4/3 pi r^3), for a cube of side ``cell``."""
    if not (0.0 < porosity < 1.0):
        raise AmfeError(f"the porosity must lie strictly between 0 and 1, got {porosity!r}")
    if not (radius > 0 and cell > 0):
        raise AmfeError("the sphere radius and the cell side must be positive lengths")
    return -math.log(porosity) * cell ** 3 / (4.0 / 3.0 * math.pi * radius ** 3)


def overlapping_spheres(porosity, radius, cell, seed=0):
    """(centers (N, 3) [m], radii (N,) [m]) of a periodic cube [0, cell)^3 of random
    overlapping spheres of one ``radius`` [m] whose expected porosity is ``porosity``.

    N is :func:`expected_count` rounded (a fixed number, which spreads the porosity
    less than a Poisson-drawn one); the porosity is (1 - v / V)^N in expectation
    over the centres, not per cell: report the cell's own.
    """
    rng = np.random.default_rng(seed)
    n = max(1, int(round(expected_count(porosity, radius, cell))))
    return rng.uniform(0.0, cell, size=(n, 3)), np.full(n, float(radius))

"""Kinematic uniform boundary conditions (KUBC, docs/model.md, section 5).

Boundary particles (centre within one maximum radius of a face of the
centres' bounding box) get the translation u = eps (x - x_c) for each of the
six unit macro-strains; their rotations and every other DOF stay free. All six
cases prescribe the same DOFs: one operator, one preconditioner set-up.
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.model.averages import box_center, unit_strains
from amfe.model.loadcase import Group
from amfe.vocab import CASE_NAMES


def kubc_groups(frame):
    """One :class:`~amfe.solvers.loadcases.Group` of the six KUBC cases of ``frame``."""
    x = frame.centers
    boundary = boundary_particles(x, frame.radii)
    fixed = np.zeros((len(x), 6), bool)
    fixed[boundary, :3] = True
    values = []
    for eps in unit_strains():
        v = np.zeros((len(x), 6))
        v[:, :3] = kubc_displacements(x, box_center(x), eps)  # on every particle
        values.append(v)
    # The solution is the affine field plus a fluctuation: starting CG from the
    # affine field everywhere (rotations zero) saves iterations.
    return [Group(fixed=fixed, values=values, names=list(CASE_NAMES), guesses=values,
                  strains=unit_strains())]


def boundary_particles(centers, radii) -> np.ndarray:
    """KUBC boundary mask (N,) bool (docs/model.md, section 5).

    A particle is on the boundary when its centre lies within one maximum
    radius (max of ``radii`` (N,) [m]) of a face of the axis-aligned bounding
    box of ``centers`` (N, 3) [m]; distances equal to the radius count.
    """
    x = np.asarray(centers, dtype=float)
    r = np.asarray(radii, dtype=float).reshape(-1)
    if x.ndim != 2 or x.shape[1] != 3 or r.shape != (x.shape[0],):
        raise AmfeError(f"boundary_particles: centres (N, 3) and radii (N,) expected, "
                        f"got {x.shape} and {r.shape}")
    if x.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    rmax = float(r.max())
    lo, hi = x.min(axis=0), x.max(axis=0)
    return np.any((x - lo <= rmax) | (hi - x <= rmax), axis=1)


def kubc_displacements(positions, center, eps) -> np.ndarray:
    """Boundary translations u = eps (x - x_c), (B, 3) [m].

    ``positions`` (B, 3) [m], ``center`` (3,) [m], ``eps`` (3, 3) [-] the
    macro-strain (or any displacement gradient).
    """
    x = np.asarray(positions, dtype=float)
    xc = np.asarray(center, dtype=float).reshape(3)
    eps = np.asarray(eps, dtype=float)
    return (x - xc) @ eps.T

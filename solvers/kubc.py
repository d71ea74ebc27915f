"""Kinematic uniform boundary conditions (KUBC, DESIGN section 5).

Boundary particles (centre within one maximum radius of a face of the
centres' bounding box) get the translation u = eps (x - x_c) for each of the
six unit macro-strains; their rotations and every other DOF stay free. All six
cases prescribe the same DOFs: one operator, one preconditioner set-up.
"""
import numpy as np

from amfe.homogenize import boundary_particles, box_center, unit_strains
from .loadcases import Group

CASE_NAMES = ("xx", "yy", "zz", "yz", "xz", "xy")


def kubc_groups(frame):
    """One :class:`~solvers.loadcases.Group` of the six KUBC cases of ``frame``."""
    x = frame.centers
    boundary = boundary_particles(x, frame.radii)
    fixed = np.zeros((len(x), 6), bool)
    fixed[boundary, :3] = True
    values = []
    for eps in unit_strains():
        v = np.zeros((len(x), 6))
        v[:, :3] = (x - box_center(x)) @ eps.T  # u = eps (x - x_c) on every particle
        values.append(v)
    # The solution is the affine field plus a fluctuation: starting CG from the
    # affine field everywhere (rotations zero) saves iterations.
    return [Group(fixed=fixed, values=values, names=list(CASE_NAMES), guesses=values)]

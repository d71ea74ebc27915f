"""Load cases as plain data: which DOFs a boundary condition prescribes, and to what.

A :class:`Group` is a set of load cases that prescribe the same DOFs (with
different values): the solvers build one constrained operator and one
preconditioner per group and solve each case against it (docs/model.md,
section 5). KUBC is one group of six cases; the mixed conditions are six
groups of one. Pure numpy: the boundary-condition modules build groups, the
PETSc layer (amfe.solvers) solves them.
"""
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Group:
    """Load cases sharing their prescribed DOFs.

    fixed (n,6) bool: prescribed DOFs; values: list of (n,6) arrays, one per
    case (entries outside ``fixed`` are ignored); names: case names;
    null_modes: (m, n, 6) rigid modes the constraints leave free (the
    operator is then singular and CG works in their orthogonal complement;
    the right-hand sides are consistent because K annihilates them);
    guesses: optional list of (n,6) initial guesses, one per case;
    forces: optional list of (n,6) applied nodal forces and couples, one per
    case, added to the right-hand side (entries on ``fixed`` DOFs are
    ignored: a prescribed DOF takes its reaction instead). SUBC's boundary
    loads and the periodic condition's crossing-bond loads are forces
    (docs/model.md, section 9); smoothed_aggregation: the block solve keeps
    GAMG's smoothed aggregation and Chebyshev degree 2 (PETSc's defaults)
    instead of its unsmoothed ones, for frames that nothing anchors but one
    particle (SUBC; large periodic tori), whose iterations grow with the bed
    under unsmoothed aggregation (:func:`amfe.solvers.blocksolve.with_block_defaults`).
    smoothed_rtol_max: the largest rtol at which ``smoothed_aggregation``
    holds (periodic tori: at the second-order default rtol 1e-5 unsmoothed
    aggregation is cheaper at every size measured).
    strains: optional (k, 3, 3) macro-strains when case i prescribes exactly
    the translations eps_i (x - x_c) (KUBC): the average then corrects the
    reaction moments to second order in the solver's error
    (:mod:`amfe.solvers.correction`). adjoint: optional (m, n, 6) loads of the averages'
    adjoint problems (zero on ``fixed``): KUBC's strain on free hull vertices,
    :func:`amfe.solvers.correction.strain_loads`.
    """

    fixed: np.ndarray
    values: list
    names: list
    null_modes: np.ndarray = field(default=None)
    guesses: list = field(default=None)
    forces: list = field(default=None)
    smoothed_aggregation: bool = False
    smoothed_rtol_max: float = float("inf")
    strains: np.ndarray = field(default=None)
    adjoint: np.ndarray = field(default=None)


def rigid_body_modes(points, center=None):
    """(6, 6n) rigid-body modes of n nodes with DOFs (u_x, u_y, u_z, th_x, th_y, th_z).

    Modes 0-2 translate; modes 3-5 rotate about the axes through ``center``
    (default: the centroid of ``points`` (n,3)): a rotation omega moves u by
    omega x (x - center) AND sets theta = omega. (PETSc's
    MatNullSpaceCreateRigidBody covers 3-DOF nodes only.)
    """
    center = points.mean(axis=0) if center is None else np.asarray(center, float)
    rel = points - center
    modes = np.zeros((6, points.shape[0], 6))
    for a in range(3):
        omega = np.eye(3)[a]
        modes[a, :, a] = 1.0
        modes[3 + a, :, :3] = np.cross(omega, rel)
        modes[3 + a, :, 3 + a] = 1.0
    return modes.reshape(6, -1)

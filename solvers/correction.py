"""Averages to second order in the solver's error (docs/model.md, sections 5 and 9).

Each condition's constants are linear functionals of the solutions whose
adjoint solutions are the group's own solutions. An iterate x_j with residual
r_j = b_j - A x_j (over the free DOFs; prescribed ones set exact) gives
them with an error linear in x_j's error e_j, and that error has a closed
form. KUBC: C_ij = eps_i : sigma_j is the work of case i's prescribed
translations a_i against case j's reactions over V, its adjoint minus case
i's exact solution on the free DOFs, so

    a_i . f_j(x*_j) = a_i . f_j(x_j) - x*_i . r_j    (exactly).

SUBC (S_ij = F_i . x_j / V) and the periodic condition (C_ij = (W0_ij -
F_i . x_j) / V) take the loads' work, whose adjoint is plus case i's
solution: F_i . x*_j = F_i . x_j + x*_i . r_j. With the computed x_i in
place of x*_i what is left is e_i^T A e_j, quadratic in the iterates' errors
(the dual-weighted residual correction of goal-oriented error estimation).
Everything needed is at hand after the six solves: D_ij = x_i . r_j, one
(6, 6) product. Pure numpy: the solvers compute D, the averages apply it.
"""
import numpy as np

from amfe.model.averages import hull_of, voigt_strain
from amfe.vocab import VOIGT_PAIRS

CORRECTED_RTOL = 1e-5
"""Default rtol of CG + GAMG where the constants are second order in the
solver's error (:func:`second_order_kubc`, :func:`second_order_loads`), from
``--solver gamg`` and ``auto``
alike. Measured against Cholesky or rtol 1e-12 (docs/benchmarks.md, "The
reaction stress to second order"): the nine constants within about 1e-7
relative, closer than the uncorrected stress got at rtol 1e-8, in about half
the iterations."""

STRAIN_ADJOINT_DEFAULT = "no"
"""-amfe_strain_adjoint's default. "yes": KUBC beds with free hull vertices solve the strain's six
adjoints and take :data:`CORRECTED_RTOL`. It does not pay end to end on paper-scale beds (1.25x
the wall of rtol 1e-7 with the per-bed smoothed aggregation; docs/benchmarks.md, "The strain to
second order"), so such beds keep the first-order default rtol."""


FREE_SHARE_MAX = 1e-3
"""A first-order KUBC bed (free hull vertices) whose free vertices carry at most this share of
the strain integral (:func:`free_strain_share`) solves at :data:`CORRECTED_RTOL` with smoothed
aggregation, like a second-order one. Measured (docs/benchmarks.md, "Free hull vertices: rtol by
their share"): at rtol 1e-5 with smoothed aggregation the constants' error was at most 6.8e-4
times the share (the 57 `small` beds with free hull vertices among seed 2's records 0-299, and
paper beds 107, 301, 304), so at most 6.8e-7 here, 15x inside the label contract; unsmoothed
aggregation reached 1.1e-2 times it, hence smoothing. Beds beyond the paper's size (200 k
particles) are not measured: the ratio was largest on the largest bed."""


def takes_correction(group):
    """Whether a :class:`~amfe.model.loadcase.Group`'s cross products D are computed: six
    cases (one operator) and no free rigid modes. Its condition's average decides the rest."""
    return group.null_modes is None and len(group.values) == 6


def second_order_loads(frame, groups):
    """SUBC and periodic: with D applied the constants are second order (the strain is the
    applied one, or the loads' work, exactly)."""
    return all(map(takes_correction, groups))


def second_order_kubc(frame, groups):
    """Whether KUBC's constants are second order in the solver's error.

    The correction makes the stress so; the Bagi strain (a hull-boundary
    integral of the hull vertices' translations) is exact when every hull
    vertex of the frame's centres is prescribed, and first order in the error
    of any that is free (a bed whose hull is not its bounding box: skipped
    pieces at a corner). Such beds keep the uncorrected default rtol
    (corrected all the same).
    """
    free = free_hull_vertices(frame, groups)
    return free is not None and free.size == 0


def free_hull_vertices(frame, groups, hull=None):
    """KUBC's hull vertices (indices) with a free translation, or None where the groups are not
    one KUBC group that :func:`takes_correction` (rank 0: qhull)."""
    if not all(g.strains is not None and g.forces is None and takes_correction(g)
               for g in groups):
        return None
    held = np.logical_and.reduce([g.fixed[:, :3].all(axis=1) for g in groups])
    v = (hull or hull_of(frame.centers)).vertices
    return v[~held[v]]


def free_strain_share(frame, groups, hull=None):
    """:func:`strain_share` of the free hull vertices (:func:`free_hull_vertices`) of a frame,
    or None where those are None."""
    hull = hull or hull_of(frame.centers)
    free = free_hull_vertices(frame, groups, hull)
    return None if free is None else strain_share(hull, frame.centers, free)


def strain_share(hull, centers, free):
    """The share, in [0, 1], of the hull vertices ``free`` (indices into centers (n, 3)) in
    the Bagi strain integral.

    The strain is H = sum_v u_v W_v (:func:`strain_weights`), and with u_v = eps (x_v - x_c)
    the sum gives eps exactly (sum_v (x_v - x_c) W_v = I). Errors e_v at the free vertices
    move it by sum_free e_v W_v; with |e_v| at most a fraction eta of |eps| |x_v - x_c|, that
    is at most eta |eps| times sum_free |x_v - x_c| |W_v|, which this share is of the same sum
    over every vertex (x_c: the centres' mean).
    """
    vertices, w = strain_weights(hull)
    arm = np.linalg.norm(centers[vertices] - centers.mean(axis=0), axis=1)
    size = arm * np.linalg.norm(w, axis=1)
    return float(size[np.isin(vertices, free)].sum() / size.sum())


def strain_weights(hull):
    """(vertices (h,), W (h, 3)) with the Bagi gradient H_ab = sum_v u_v,a W_v,b
    (:func:`amfe.model.averages.bagi_strain`: W_v = (1/V) sum of A_f n_f / 3 over v's facets)."""
    w = np.zeros((int(hull.facets.max()) + 1, 3))
    for c in range(3):
        np.add.at(w, hull.facets[:, c], hull.areas[:, None] * hull.normals / 3.0)
    return hull.vertices, w[hull.vertices] / hull.volume


def strain_loads(vertices, weights, fixed):
    """(6, n, 6): the gradients g_m of the six Voigt strain components (engineering shears)
    with respect to the free DOFs (zero on ``fixed`` (n, 6)), the adjoint loads A z_m = g_m
    (docs/model.md section 5, "Strain to second order")."""
    g = np.zeros((6,) + fixed.shape)
    for m, (a, b) in enumerate(VOIGT_PAIRS):
        g[m, vertices, a] += weights[:, b]
        if a != b:
            g[m, vertices, b] += weights[:, a]
    g[:, fixed] = 0.0
    return g


def never(frame, groups):
    """The mixed conditions: six groups of one case, no cross products."""
    return False


def moment_corrections(strains, cross):
    """Corrections (k, 3, 3) to k cases' reaction moments, symmetric, frame units.

    strains (k, 3, 3): case i prescribes the translations eps_i (x - x_c) and
    nothing else (no applied forces, no free rigid modes); cross (k, k):
    D_ij = x_i . r_j, case i's solution dotted with case j's true residual
    b_j - A x_j over the free DOFs (zero on the prescribed ones). The corrected
    moment M_j + dM_j satisfies eps_i : (M_j + dM_j) = eps_i : M_j - D_ij for
    every i. Needs the k strains to span the symmetric tensors (k = 6); returns
    None otherwise.
    """
    E = np.array([voigt_strain(e) for e in strains])  # (k, 6) engineering Voigt
    D = np.asarray(cross, dtype=float)
    if E.shape != (6, 6) or D.shape != (6, 6) or np.linalg.cond(E) > 1e8:
        return None
    # eps_i : S = sum_m E_im s_m with s the Voigt vector (xx, yy, zz, yz, xz, xy) of a
    # symmetric S, so the corrections' Voigt vectors are the columns of -E^-1 D.
    s = np.linalg.solve(E, -D)
    out = np.zeros((6, 3, 3))
    for m, (a, b) in enumerate(VOIGT_PAIRS):
        out[:, a, b] = out[:, b, a] = s[m]
    return out


def relative_size(corrections, moments):
    """Largest ||dM_j||_F / ||M_j||_F: what the correction changed, a measure of the
    uncorrected error (the corrected one is about its square)."""
    sizes = [np.linalg.norm(d) / (np.linalg.norm(m) or 1.0)
             for d, m in zip(corrections, moments)]
    return float(max(sizes)) if sizes else 0.0

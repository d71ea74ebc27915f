"""A bed's multigrid for CG + GAMG: unsmoothed aggregation on whole beds, smoothed on scanned ones.

The block path's defaults (:data:`amfe.solvers.blocksolve.BLOCK_DEFAULTS`:
unsmoothed aggregation, Chebyshev of degree 1) were chosen on the fully
scanned bed, where CG takes 7-15 iterations and GAMG's set-up dominates. A
scanned bed (raster tracks with skipped pieces) has thin tracks and pieces
joined by few bonds: unsmoothed aggregation then takes 66-75 iterations on a
paper-scale bed, smoothed aggregation 28-34, for twice the set-up
(issue 33; docs/benchmarks.md, "Multigrid per bed"). The solves then dominate, so
smoothing pays there and not on whole beds.

:func:`multigrid_features` measures, from the frame alone (a user's bed has
no scan record), the share of particles with few bonds: a particle inside a
whole bed has 12 neighbours, on a face 8-9, on an edge 5-7; the cut sides of
tracks and the holes a skipped piece leaves add faces and edges, and
particles left hanging with 1-4 bonds. Smoothed beds also take Chebyshev of
degree 2. :func:`choose_multigrid` smooths when
that share exceeds :data:`LOW_SHARE_MIN` and the constants are first order in
the solver's error (free hull vertices: rtol 1e-7, many iterations). A user's own
``-pc_gamg_agg_nsmooths`` always wins (the choice then adds nothing).
"""
import numpy as np

from amfe.solvers.blocksolve import galerkin_algorithm
from amfe.solvers.correction import CORRECTED_RTOL

LOW_BONDS = 6
"""A particle with at most this many bonds counts as weakly held (an edge or a dangling piece)."""

LOW_SHARE_MIN = 0.02
"""Smoothed aggregation when the share of weakly held particles exceeds this (docs/benchmarks.md,
"Multigrid per bed")."""

CHOSEN_OPTIONS = ("pc_gamg_agg_nsmooths", "matptap_via", "mg_levels_ksp_max_it")
"""The PETSc options the choice sets; each one the user sets is left to the user."""


def multigrid_features(frame):
    """{"low_share": share of particles with at most :data:`LOW_BONDS` bonds, "bonds_per_particle":
    mean coordination} of a frame (bonds (i, j) over n_particles; milliseconds)."""
    n = frame.n_particles
    b = frame.bonds
    deg = np.bincount(np.concatenate([b.i, b.j]), minlength=n)
    return {"low_share": float((deg <= LOW_BONDS).mean()) if n else 0.0,
            "bonds_per_particle": float(deg.mean()) if n else 0.0}


def choose_multigrid(features, n_ranks, corrected=False, user_options=(), loosened=False):
    """(ksp_options, reason) of GAMG's aggregation for one bed.

    features: :func:`multigrid_features` of the frame; n_ranks: the ranks the
    matrix spans (the Galerkin product's algorithm,
    :func:`~amfe.solvers.blocksolve.galerkin_algorithm`); corrected: the
    constants are second order in the solver's error (:mod:`amfe.solvers.correction`:
    a bed whose hull vertices are all prescribed solves at rtol 1e-5 in a few
    iterations, where set-up dominates: never smoothed); user_options: PETSc
    option names the user set (per solve or in the database): an explicit
    ``pc_gamg_agg_nsmooths`` leaves everything to the user; loosened: a first-order bed
    solved at rtol 1e-5 (:attr:`amfe.solvers.choice.Problem.loosened`), always smoothed:
    its error bound was measured so (unsmoothed aggregation left 16x more error).
    """
    if "pc_gamg_agg_nsmooths" in user_options:
        return {}, "-pc_gamg_agg_nsmooths given"
    share = features["low_share"]
    if corrected:
        return {}, (f"unsmoothed aggregation: second-order constants (rtol {CORRECTED_RTOL:g}: "
                    "few iterations, set-up dominates)")
    if share > LOW_SHARE_MIN or loosened:
        # Chebyshev of PETSc's degree 2 (the block path's is 1): the same wall on two
        # paper-scale beds, and every case within 30 iterations (docs/benchmarks.md)
        opts = {"pc_gamg_agg_nsmooths": "1", "matptap_via": galerkin_algorithm(n_ranks),
                "mg_levels_ksp_max_it": "2"}
        opts = {k: v for k, v in opts.items() if k not in user_options}
        why = (f"rtol {CORRECTED_RTOL:g} on a first-order bed whose free hull vertices weigh "
               "little" if loosened and share <= LOW_SHARE_MIN else
               f"{share:.3f} of the particles have <= {LOW_BONDS} bonds (> {LOW_SHARE_MIN:g})")
        return opts, f"smoothed aggregation: {why} and the constants are first order"
    return {}, (f"unsmoothed aggregation: {share:.3f} of the particles have <= {LOW_BONDS} "
                f"bonds (<= {LOW_SHARE_MIN:g})")

"""Which solve labels a bed: the cheapest method that keeps the constants' accuracy contract.

The contract is the label's accuracy, not the method: every constant within
:data:`CONTRACT` (1e-5) relative of a tight reference (CG + GAMG at rtol
1e-12). Two methods meet it (measured on 60 held-out `small` beds, docs/benchmarks.md):

- ``cholesky``: one sparse Cholesky factorisation of the constrained operator
  (CHOLMOD, or MUMPS when PETSc lacks SuiteSparse), then the six right-hand
  sides: exact to round-off (1e-12 from the reference). One rank only: the
  factor's fill grows much faster with the bed than GAMG's work does.
- ``gamg``: CG + GAMG. Its constants carry about 3-30x rtol of error, worst on
  small sparse beds; ``auto`` runs it at :data:`GAMG_RTOL_AUTO` (1e-7: at most
  5.0e-6 on the beds auto sends to it with the block path, 7.3e-6 over all 60),
  ``--solver gamg`` at the 1e-8 default. Where the condition's average is
  second order in the solver's error (:mod:`amfe.solvers.correction`: KUBC on
  a bed whose hull vertices are all prescribed, SUBC, periodic) both run at
  rtol 1e-5 instead, about 1e-7 from the reference, and so does a KUBC bed whose free
  hull vertices carry little of the strain (:attr:`Problem.loosened`).

:func:`choose_solver` decides per bed from the predicted fill of a
factorisation (:func:`solve_features`, a few milliseconds), never from the
particle count alone, and always picks GAMG when the matrix spans several ranks.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from amfe.errors import AmfeError
from amfe.model.memory import direct_bytes
from amfe.solvers.correction import CORRECTED_RTOL, FREE_SHARE_MAX
from amfe.solvers.inputs import given_options
from amfe.solvers.ksp import DEFAULT_RTOL
from amfe.solvers.petsclib import PETSc

METHODS = ("auto", "gamg", "cholesky")

CONTRACT = 1e-5
"""Largest relative error of a constant, against a tight reference, that a label may carry."""

GAMG_RTOL_AUTO = 1e-7
"""rtol of CG + GAMG when ``auto`` picks it (1e-6 reached 9.2e-6 on one of 20 beds: unsafe)."""

FILL_RATIO_MAX = 34.0
"""Cholesky when the predicted fill (:func:`solve_features`) is at most this. Fitted on 60
`small` beds (fill 7.7-57.7; run/probes/solver_choice.py, docs/benchmarks.md) against the
block GAMG path of issue 17: the total cost is flat within 1 % for thresholds 30-38 and 8 %
below the first fit's 48, which predated that path (Cholesky then won on 49 of 60 beds,
now on 29)."""

MAX_DIRECT_PARTICLES = 20_000
"""Never factorise beyond this many kept particles: a fully scanned 15 540-particle bed
already factorises in 3-5x GAMG's time (docs/report.md, section 1)."""

# PETSc options whose presence means the user chose the method: auto then leaves it alone.
USER_METHOD_OPTIONS = ("ksp_type", "pc_type", "pc_factor_mat_solver_type")


def cholesky_package():
    """"cholmod" when PETSc has SuiteSparse, else "mumps", else None."""
    for name, pkg in (("cholmod", "suitesparse"), ("mumps", "mumps")):
        if PETSc.Sys.hasExternalPackage(pkg):
            return name
    return None


def solve_features(frame):
    """Cheap features of a frame for :func:`choose_solver` (a few ms on a `small` bed).

    n_particles, n_bonds: the kept frame; fill_ratio: the envelope (profile)
    of the particle graph in reverse Cuthill-McKee order, plus the diagonal,
    over the upper triangle's non-zeros (diagonal + bonds). The envelope
    bounds the Cholesky factor of that ordering, so it predicts the fill; the
    6x6 blocks cancel in the ratio, which is therefore also the fill ratio of
    the 6n x 6n operator.
    """
    n, b = frame.n_particles, frame.bonds
    G = sp.coo_matrix((np.ones(len(b.i)), (b.i, b.j)), shape=(n, n))
    G = (G + G.T).tocsr()
    p = reverse_cuthill_mckee(G, symmetric_mode=True)
    Gp = G[p][:, p].tocsr()
    rows = np.repeat(np.arange(n), np.diff(Gp.indptr))
    first = np.arange(n)
    np.minimum.at(first, rows, Gp.indices)   # first column of each row's envelope
    profile = float((np.arange(n) - first).sum())
    return {"n_particles": int(n), "n_bonds": int(len(b.i)),
            "fill_ratio": (profile + n) / float(len(b.i) + n)}


@dataclass(frozen=True)
class Problem:
    """What the operator is, for :func:`choose_solver`: singular (the constrained
    operator keeps rigid modes, the mixed conditions, which a factorisation cannot
    take); corrected (the condition's reaction stress takes the second-order
    correction, :mod:`amfe.solvers.correction`); free_share: on a first-order KUBC
    bed, the free hull vertices' share of the strain integral
    (:func:`~amfe.solvers.correction.free_strain_share`), else None."""

    singular: bool = False
    corrected: bool = False
    free_share: float = None

    @property
    def loosened(self):
        """A first-order bed whose free hull vertices weigh so little that rtol 1e-5 keeps the
        contract (:data:`~amfe.solvers.correction.FREE_SHARE_MAX`, with smoothed aggregation)."""
        return (not self.corrected and self.free_share is not None
                and self.free_share <= FREE_SHARE_MAX)


def choose_solver(features, nranks, requested="auto", rtol=None, package="cholmod",
                  user_options=(), problem=Problem(), check_memory=None):
    """(method, reason, rtol, ksp_options) for one bed.

    features: the dict of :func:`solve_features` (or a callable that returns
    it, called only when needed); nranks: ranks the matrix spans; requested:
    "auto", "gamg" or "cholesky"; rtol: an explicit tolerance (None: the
    method's default; GAMG only); package: the factorisation package, None
    when PETSc has none; user_options: the PETSc options the user set (one of
    :data:`USER_METHOD_OPTIONS` among them makes auto keep the iterative path
    those options configure); problem: a :class:`Problem` (singular, corrected, free_share);
    check_memory(estimate [bytes], what): raises AmfeError when an estimate
    is over the memory limit (:func:`amfe.model.memory.direct_bytes` of the
    factorisation): auto then takes GAMG, ``cholesky`` is refused. A corrected
    problem's default rtol :data:`~amfe.solvers.correction.CORRECTED_RTOL` serves
    ``gamg`` and ``auto`` alike, and so does a :attr:`Problem.loosened` one's (the
    caller then smooths the aggregation). The returned rtol is None for Cholesky.
    """
    if requested not in METHODS:
        raise AmfeError(f"unknown solver {requested!r}; choose one of {', '.join(METHODS)}")
    singular = problem.singular
    loose = ""
    if rtol is None and problem.loosened:
        loose = (f"; rtol {CORRECTED_RTOL:g}: the free hull vertices carry {problem.free_share:.1e}"
                 f" of the strain (<= {FREE_SHARE_MAX:g})")
    if rtol is None and (problem.corrected or problem.loosened):
        rtol = CORRECTED_RTOL
    method, reason, rtol, options = _choose(features, nranks, requested, rtol, package,
                                            user_options, singular, check_memory)
    return method, reason + (loose if method == "gamg" else ""), rtol, options


def _choose(features, nranks, requested, rtol, package, user_options, singular, check_memory):
    """:func:`choose_solver` once the rtol is settled."""
    direct = {"ksp_type": "preonly", "pc_type": "cholesky",
              "pc_factor_mat_solver_type": package, "amfe_operator_type": "aij"}
    if requested == "gamg":
        return "gamg", "asked for (--solver gamg)", DEFAULT_RTOL if rtol is None else rtol, {}
    if requested == "cholesky":
        if nranks > 1:
            raise AmfeError(f"--solver cholesky runs on one rank; this bed is solved on {nranks} "
                            "ranks: use --solver gamg or auto, or run it on one rank "
                            "(amfe dataset: --ranks-per-bed 1)")
        if singular:
            raise AmfeError("--solver cholesky cannot factorise these boundary conditions: "
                            "they leave rigid modes free (a singular operator); use --solver gamg")
        if package is None:
            raise AmfeError("--solver cholesky needs PETSc with CHOLMOD or MUMPS; this PETSc "
                            "has neither: use --solver gamg")
        if check_memory is not None:
            _check_factor(features() if callable(features) else features, check_memory)
        return "cholesky", f"asked for (--solver cholesky, {package})", None, direct
    auto_rtol = GAMG_RTOL_AUTO if rtol is None else rtol
    given = [k for k in USER_METHOD_OPTIONS if k in user_options]
    if given:
        return "gamg", (f"auto: the PETSc options {', '.join('-' + k for k in given)} choose the "
                        "method"), auto_rtol, {}
    if singular:
        return "gamg", "auto: the operator has free rigid modes (singular)", auto_rtol, {}
    if nranks > 1:
        return ("gamg", f"auto: the matrix spans {nranks} ranks (Cholesky is one-rank)",
                auto_rtol, {})
    if package is None:
        return "gamg", "auto: this PETSc has no Cholesky package", auto_rtol, {}
    f = features() if callable(features) else features
    if f["n_particles"] > MAX_DIRECT_PARTICLES:
        return "gamg", (f"auto: {f['n_particles']} particles > {MAX_DIRECT_PARTICLES}, too many "
                        "to factorise"), auto_rtol, {}
    if f["fill_ratio"] <= FILL_RATIO_MAX and check_memory is not None:
        try:
            _check_factor(f, check_memory)
        except AmfeError as exc:
            return "gamg", f"auto: {exc}", auto_rtol, {}
    if f["fill_ratio"] <= FILL_RATIO_MAX:
        return "cholesky", (f"auto: predicted fill {f['fill_ratio']:.1f} <= {FILL_RATIO_MAX:g} "
                            f"(RCM envelope / non-zeros), {package}"), None, direct
    return "gamg", (f"auto: predicted fill {f['fill_ratio']:.1f} > {FILL_RATIO_MAX:g} "
                    "(RCM envelope / non-zeros)"), auto_rtol, {}


def _check_factor(f, check_memory):
    check_memory(direct_bytes(f["n_particles"], f["n_bonds"], f["fill_ratio"]),
                 f"factorising {f['n_particles']} particles (predicted fill {f['fill_ratio']:.1f})")


def shown_method(method, ksp_options=None):
    """How the progress line names the method: ``method``, or "KSP + PC" where the PETSc
    options (per solve, or of the call in the database) set the KSP or the PC ("-pc_type
    hypre" printed "solver: gamg" before the summary said cg+hypre)."""
    given = given_options(("ksp_type", "pc_type"), ksp_options)
    if method == "cholesky" or not given:
        return method
    mine = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}
    db = PETSc.Options()
    pick = {k: str(mine[k]) if k in mine else db.getString(k) if db.hasName(k) else d
            for k, d in (("ksp_type", "cg"), ("pc_type", "gamg"))}
    return f"{pick['ksp_type']} + {pick['pc_type']} (the PETSc options given)"

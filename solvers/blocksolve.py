"""The load cases of one group through k CGs that share every product and V-cycle.

A group's cases share the operator and GAMG's set-up (docs/model.md, section
5), so the k solves can read each matrix once per sweep instead of k times:
k CGs are advanced together, each product is a k-column product and each
preconditioner application a block V-cycle (:mod:`amfe.solvers.blockcycle`).
Each column keeps its own alpha, beta, convergence test and stopping reason,
exactly as PETSc's KSPCG with KSPConvergedDefault (the KSP's norm type, rtol,
atol, dtol, max_it; with an initial guess the reference is ||M b||), so the
iteration counts are those of the one-at-a-time path. Every decision uses
globally reduced numbers: every rank takes the same branch and a column that
stops (converged or not) is frozen while the others go on, with no hang.

:func:`block_path_applies` says when :meth:`ConstrainedOperator.solve_all
<amfe.solvers.operator.ConstrainedOperator.solve_all>` takes this path;
:func:`solve_block` runs it, and ``solve_all`` holds every case to the
convergence contract (:func:`amfe.solvers.ksp.check_solution`) as the
one-at-a-time path does, through a :class:`ColumnKSP` per case.
"""
import logging
import time
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.solvers.blockcycle import BlockUnsupported, BlockVCycle
from amfe.solvers.petsclib import PETSc

# KSPConvergedReason values (PETSc 3.18)
RTOL, ATOL, ITS, DTOL, INDEF_PC, NANORINF, INDEF_MAT = 2, 3, -3, -4, -8, -9, -10
NORMS = {1: "preconditioned", 2: "unpreconditioned", 3: "natural"}  # KSPNormType
CHECK_TOLERANCE = 1e-4
"""Largest relative difference of a block V-cycle column from PCApply accepted;
above it the group is solved one case at a time. The Chebyshev targets' six
digits make about 1e-6 (:mod:`amfe.solvers.blockcycle`); a coarse grid that
PETSc's LU shifts, a W-cycle or another smoother make 1e-3 and more."""


BLOCK_DEFAULTS = {"pc_gamg_agg_nsmooths": "0", "mg_levels_ksp_max_it": "1"}
"""PETSc options the block path sets unless given: unsmoothed aggregation (a cheaper
GAMG set-up with less memory, for more iterations, which the block path makes
cheap) and Chebyshev of degree 1 on every level (PETSc's default is 2: a V-cycle
then reads the fine matrix fewer times). The measurements that chose them are in
docs/benchmarks.md, "Figures quoted in the code", and "Six right-hand sides at once"."""


def galerkin_algorithm(n_ranks):
    """PETSc's algorithm for GAMG's Galerkin products P^T A P under smoothed aggregation.

    Smoothed aggregation's prolongators are denser, and PETSc's default
    ("scalable", a sparse accumulator per row) spends most of SUBC's set-up in
    them. Forming R = P^T first ("rap", serial matrices) or a dense row
    accumulator ("nonscalable", parallel ones; an array the length of the
    coarse grid) halve it, with the same iterations and constants
    (docs/benchmarks.md, "SUBC's set-up" and "Figures quoted in the code"). The
    unsmoothed defaults gain nothing.
    """
    return "rap" if n_ranks == 1 else "nonscalable"


def with_block_defaults(ksp_options, smoothed=False, n_ranks=1):
    """``ksp_options`` plus the :data:`BLOCK_DEFAULTS` set neither there nor in the database.

    smoothed: the group's ``smoothed_aggregation`` (a frame held at one particle
    only: SUBC, large periodic tori; no prescribed boundary, loads as forces).
    It keeps smoothed aggregation and PETSc's Chebyshev degree: with the defaults the
    iterations grow with the bed (SUBC 45 -> 84 from 0.6 to 1.2 mm, 113-123
    with degree 1, against 15-16 smoothed at both sizes; periodic 29 -> 38,
    against 11), 1.7x (SUBC) and 1.1-1.3x (periodic) slower end to end at
    1.2 mm. Its Galerkin products take :func:`galerkin_algorithm` (n_ranks:
    the communicator's size); docs/benchmarks.md, "SUBC's set-up".
    """
    given = ksp_options or {}
    defaults = ({"matptap_via": galerkin_algorithm(n_ranks)} if smoothed
                else BLOCK_DEFAULTS)
    db = PETSc.Options()
    return {**{k: v for k, v in defaults.items() if k not in given and not db.hasName(k)},
            **given}


def block_path_applies(ksp, n_cases, option, diagnose):
    """True when a group's cases go through the block CG.

    n_cases >= 2, the KSP is CG with GAMG (or MG), -amfe_block is not "no",
    and no diagnosis is asked for (its eigenvalue estimates come from KSPCG).
    Level smoothers other than Chebyshev + Jacobi are found later (BlockUnsupported).
    """
    return (_wanted(option, n_cases, diagnose) and ksp.getType() == "cg"
            and ksp.getPC().getType() in ("gamg", "mg") and not _watched(ksp))


#: Options that watch a KSPSolve (its monitors, its view, its reason): the block CG makes no
#: KSPSolve, so with one of them the group is solved one case at a time, with a warning.
WATCH_OPTIONS = ("ksp_monitor", "ksp_view", "ksp_converged_reason")


def _watched(ksp):
    """The watching options given for the outer KSP ("-ksp_monitor", ...), warned about on rank 0
    once per process; True if any."""
    db = PETSc.Options()
    given = sorted(n for n in db.getAll() if n.startswith(WATCH_OPTIONS))
    if given and not _watch_warned and ksp.getComm().getRank() == 0:
        _watch_warned.append(True)
        logging.getLogger("amfe.solvers").warning(
            f"{' '.join('-' + n for n in given)}: the six load cases are solved one at a time "
            "(not in one block CG), so that PETSc can print them; the same iterations and "
            "constants, a little slower")
    return bool(given)


_watch_warned = []


def block_path_expected(n_cases, option, diagnose):
    """:func:`block_path_applies` before the KSP exists, from the options database.

    The operator then skips its SBAIJ copy (the block products use AIJ; a
    fallback to one case at a time then multiplies with AIJ, same results).
    """
    db = PETSc.Options()
    return (_wanted(option, n_cases, diagnose) and db.getString("ksp_type", "cg") == "cg"
            and db.getString("pc_type", "gamg") == "gamg")


def _wanted(option, n_cases, diagnose):
    if option not in ("yes", "no"):
        raise AmfeError(f"-amfe_block {option!r}: give yes (six cases in one block CG, the "
                        "default) or no (one case at a time)")
    return option == "yes" and n_cases >= 2 and not diagnose


@dataclass
class BlockColumn:
    """One case's outcome of the block CG: u (a PETSc Vec, the caller destroys it),
    iterations, residual (true ||b - A x|| / ||b||), seconds (the group's time / k),
    and ksp: a :class:`ColumnKSP` for :func:`amfe.solvers.ksp.check_solution`."""

    u: object
    iterations: int
    residual: float
    seconds: float
    ksp: object

    @property
    def indefinite(self):
        return self.ksp.getConvergedReason() == INDEF_PC


class ColumnKSP:
    """What a KSP would say about one column: its reason, iterations and last residual
    norm; type, preconditioner and tolerances those of the shared KSP."""

    def __init__(self, ksp, reason, iterations, rnorm):
        self._ksp, self._reason, self._its, self._rnorm = ksp, int(reason), int(iterations), rnorm

    def getConvergedReason(self):
        return self._reason

    def getIterationNumber(self):
        return self._its

    def getResidualNorm(self):
        return float(self._rnorm)

    def getTolerances(self):
        return self._ksp.getTolerances()

    def getType(self):
        return self._ksp.getType()

    def getPC(self):
        return self._ksp.getPC()


@dataclass
class BlockCG:
    """The state of k CGs: blocks (m, k) and per-column scalars, the same on every rank."""

    X: np.ndarray
    R: np.ndarray
    Z: np.ndarray
    rz: np.ndarray
    ref: np.ndarray
    rnorm: np.ndarray
    reason: np.ndarray
    its: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def active(self):
        return self.reason == 0


def solve_block(ksp, bs, X0, backend="auto", info=None, prescribed=None, monitor=None):
    """Solve A x_j = b_j for every case j with k CGs sharing one block V-cycle.

    ksp: a set-up KSP (CG with GAMG); bs: k right-hand side Vecs; X0: None or
    k local initial guesses (m,) each. Returns a list of :class:`BlockColumn`
    (converged or not: the caller holds each to the convergence contract), or
    None when the preconditioner is not one the block V-cycle reproduces (the
    caller then solves one at a time). Collective. ``info`` (a dict) receives
    the V-cycle check, the levels, the counts of iterations and V-cycles, and
    "cross": the (k, k) matrix x_i . r_j of the solutions and true residuals,
    summed over ranks (:mod:`amfe.solvers.correction`).
    prescribed: (local rows (p,), values (p, k)): rows whose exact values are
    known (identity rows of MatZeroRowsColumns); they are set before the true
    residuals, which are then zero there. monitor: None or a callable given (iteration, the
    largest residual norm of a running column over its stopping tolerance), from iteration 0
    (progress lines, :meth:`amfe.solvers.progress.Progress.iteration`).
    """
    t0 = time.perf_counter()
    k = len(bs)
    try:
        V = BlockVCycle(ksp.getPC(), k, backend)
    except BlockUnsupported:
        return None
    try:
        cg = _iterate(ksp, V, bs, X0, monitor)
        if cg is None:
            return None
        if prescribed is not None:
            cg.X[prescribed[0]] = prescribed[1]
        B = np.stack([b.getArray() for b in bs], axis=1)  # again: not kept while iterating
        mpi = ksp.getComm().tompi4py()
        residuals = _true_residuals(V.fine, B, cg.X, cg.R, mpi)
        del B
        if info is not None:
            # one (k, k) product over the blocks (not k^2 column dots)
            info.update(cg.info, products=V.products_per_cycle(),
                        cross=mpi.allreduce(cg.X.T @ cg.R))
    finally:
        V.destroy()
    seconds = time.perf_counter() - t0
    out = []
    for j in range(k):
        u = bs[j].duplicate()
        u.setArray(cg.X[:, j])
        out.append(BlockColumn(u, int(cg.its[j]), float(residuals[j]), seconds / k,
                               ColumnKSP(ksp, cg.reason[j], cg.its[j], cg.rnorm[j])))
    return out


def _iterate(ksp, V, bs, X0, monitor=None):
    """KSPSolve_CG for every right-hand side at once; None if V-cycle != PCApply.

    Eight (m, k) blocks live while iterating: X, R, Z, P, Q and the V-cycle's
    R, D, T on the fine level (T doubles as the work block between cycles).
    """
    rtol, atol, dtol, max_it = ksp.getTolerances()
    norm = NORMS.get(ksp.getNormType())
    if norm is None or PETSc.Options().hasName("ksp_converged_use_initial_residual_norm"):
        return None
    mpi = ksp.getComm().tompi4py()
    nullsp = ksp.getOperators()[0].getNullSpace()
    null = [v.getArray() for v in nullsp.getVecs()] if nullsp.handle else []

    def dots(*pairs):  # column-wise inner products of block pairs, summed over ranks
        return mpi.allreduce(np.array([np.einsum("ij,ij->j", a, b) for a, b in pairs]))

    def remove_null(Y):  # as KSP_PCApply does after PCApply
        for v in null:
            Y -= np.outer(v, mpi.allreduce(v @ Y))
        return Y

    def precondition(Rb, Zb):  # Z = M R
        return remove_null(V.apply(Rb, Zb))

    guess = X0 is not None
    B = np.stack([b.getArray() for b in bs], axis=1)
    X = np.stack(X0, axis=1).astype(float) if guess else np.zeros_like(B)
    Q = np.empty_like(B)
    MB = precondition(B, np.empty_like(B))
    difference = V.check(bs[0], MB[:, 0], remove_null)  # the same preconditioner as KSPSolve's?
    if not difference <= CHECK_TOLERANCE:
        return None
    R = np.subtract(B, V.fine.mult(X, Q), out=Q) if guess else B
    Z = precondition(R, np.empty_like(B)) if guess else MB
    Q = np.empty_like(B) if guess else Q
    rz, bb, rr, zz, bz, mbmb = dots((R, Z), (B, B), (R, R), (Z, Z), (B, MB), (MB, MB))
    rnorm = {"preconditioned": zz, "unpreconditioned": rr, "natural": np.abs(rz)}[norm]
    # KSPConvergedDefault: relative to ||r0|| from a zero guess, to ||b|| in the norm otherwise
    ref = rnorm if not guess else {"preconditioned": mbmb, "unpreconditioned": bb,
                                   "natural": np.abs(bz)}[norm]
    del B, MB  # (R and Z may be them: only the names go)
    k = X.shape[1]
    cg = BlockCG(X, R, Z, rz, np.sqrt(ref), np.zeros(k), np.zeros(k, int), np.zeros(k, int),
                 {"vcycle_check": difference, "norm": norm, "levels": V.describe()})
    cg.reason[bb == 0] = ATOL  # a zero right-hand side: x = 0, as KSPSolve
    cg.X[:, bb == 0] = 0.0
    _test(cg, np.sqrt(rnorm), 0, rtol, atol, dtol)
    P = np.where(cg.active, Z, 0.0)
    W = V.scratch
    it = 0
    _monitor(monitor, cg, it, rtol, atol)
    while cg.active.any() and it < max_it:
        it += 1
        _stop(cg, cg.active & ~np.isfinite(cg.rz), NANORINF, it)
        _stop(cg, cg.active & (cg.rz == 0), ATOL, it)
        _stop(cg, cg.active & ~(cg.rz > 0), INDEF_PC, it)  # z'r < 0 (or NaN)
        pq = dots((P, V.fine.mult(P, Q)))[0]
        _stop(cg, cg.active & ~np.isfinite(pq), NANORINF, it)
        _stop(cg, cg.active & ~(pq > 0), INDEF_MAT, it)
        alpha = np.where(cg.active, cg.rz / np.where(cg.active, pq, 1.0), 0.0)
        X += np.multiply(P, alpha, out=W)
        R -= np.multiply(Q, alpha, out=Q)
        precondition(R, Z)
        rz_new, rr, zz = dots((R, Z), (R, R), (Z, Z))
        _test(cg, np.sqrt({"preconditioned": zz, "unpreconditioned": rr,
                           "natural": np.abs(rz_new)}[norm]), it, rtol, atol, dtol)
        beta = np.where(cg.active, rz_new / np.where(cg.rz != 0, cg.rz, 1.0), 0.0)
        cg.rz = np.where(cg.active, rz_new, cg.rz)
        P *= beta
        P += Z
        P[:, ~cg.active] = 0.0  # stopped columns stay where they are
        _monitor(monitor, cg, it, rtol, atol)
    _stop(cg, cg.active, ITS, it)
    cg.info.update(iterations=it, vcycles=it + 1 + (1 if guess else 0))
    return cg


def _monitor(monitor, cg, it, rtol, atol):
    """monitor(it, the largest rnorm / tolerance of the running columns; 0 when none runs)."""
    if monitor is not None:
        ratio = cg.rnorm / np.maximum(rtol * cg.ref, atol)
        monitor(it, float(ratio[cg.active].max()) if cg.active.any() else 0.0)


def _stop(cg, mask, reason, it):
    cg.reason[mask] = reason
    cg.its[mask] = it


def _test(cg, rnorm, it, rtol, atol, dtol):
    """KSPConvergedDefault on every active column at iteration ``it``."""
    active = cg.active
    cg.rnorm[active] = rnorm[active]
    _stop(cg, active & ~np.isfinite(rnorm), NANORINF, it)
    ttol = np.maximum(rtol * cg.ref, atol)
    done = cg.active & (rnorm <= ttol)
    _stop(cg, done & (rnorm < atol), ATOL, it)
    _stop(cg, done & ~(rnorm < atol), RTOL, it)
    _stop(cg, cg.active & (rnorm >= dtol * cg.ref), DTOL, it)
    cg.its[cg.active] = it


def _true_residuals(A, B, X, work, mpi):
    """||b_j - A x_j|| / ||b_j|| (||r_j|| where b_j = 0) with the block product;
    ``work`` is left holding the residuals b_j - A x_j."""
    np.subtract(B, A.mult(X, work), out=work)
    rr, bb = np.sqrt(mpi.allreduce(np.array([np.einsum("ij,ij->j", work, work),
                                             np.einsum("ij,ij->j", B, B)])))
    return np.where(bb > 0, rr / np.where(bb > 0, bb, 1.0), rr)

"""KSP/PC set-up and the convergence check every solve goes through."""
import math
from contextlib import contextmanager
from dataclasses import dataclass

from amfe.errors import AmfeError
from amfe.model.tolerance import LOOSEST_RTOL
from amfe.solvers.options import refuse_crashing
from amfe.solvers.petsc import unused_options
from amfe.solvers.petsclib import PETSc

DEFAULT_RTOL = 1e-8
"""Relative residual tolerance of the CG solves. The constants come from
reaction forces, whose error is about rtol times the condition-dependent
amplification; 1e-8 leaves them accurate to ~1e-7 relative or better on the
beds measured (see the benchmark), three orders below the spread between beds,
at about one extra GAMG iteration per decade."""


RESIDUAL_FACTOR = 10.0
"""The convergence contract. A solve passes when PETSc says it converged and
its true residual r = b - A x, computed afresh, meets

    ||r|| / ||b|| <= RESIDUAL_FACTOR x max(rtol, floor),

measured as it is or in the norm the KSP tests (CG's default: the
preconditioned one, ||B r|| / ||B b||), where floor = eps ||A||_F ||x|| / ||b||
is the normwise backward-error bound below which double precision cannot
promise a residual. Measured with PETSc's default norm (amfe keeps it, so
CG's iterates and stopping points, and every constant, are those of before):

- generated beds of 600-11 000 particles, KUBC and mixed, GAMG, Jacobi and
  BoomerAMG: ||r|| / ||b|| = 0.1-1.4 x rtol (floor 1e-14 to 1e-13);
- near-critical bonds (docs/hard_cases.md): 12 x rtol at delta = 1e-5 (the
  rows of a few very stiff bonds dominate ||b||; 0.9 x rtol in the
  preconditioned norm), and at rtol 1e-12, delta 1e-9 and 2e-10, up to 700
  and 3900 x rtol against rounding floors of 1.5e-8 and 7.7e-8, with C
  within 1e-9 of a direct solve (the passes are listed in solver.notes);
- caught: -ksp_atol 1e3 (7e-2 after 0 iterations), -ksp_atol 1e-3 (3.7e-6),
  -ksp_type preonly -pc_type jacobi (0.12); a -ksp_max_it that stops CG is
  PETSc's own DIVERGED_ITS.

Switching CG to the unpreconditioned norm was measured as well: no cost on
generated beds (the same or one iteration fewer per case; 9 per case on an
11 000-particle bed either way), but near-critical interior bonds then stop
with DIVERGED_DTOL at iteration 0 (the initial guess's unpreconditioned
residual), near-critical boundary bonds lose accuracy (C off by 1.3e-6), a
bed with a weak track stops two cases on the initial guess after 0
iterations, and the constants of ordinary beds move by up to 4e-8 where the
stopping iteration moves."""



@dataclass(frozen=True)
class CaseSettings:
    """How every load case of a group is solved: rtol (CG's relative tolerance), max_it
    (iteration limit or None), ksp_options (PETSc options of these solves only, {name:
    value} or None), diagnose (eigenvalue estimates and GAMG complexities),
    accept_unconverged (keep a solve that misses the contract, with a warning)."""

    rtol: float
    max_it: int = None
    ksp_options: dict = None
    diagnose: bool = False
    accept_unconverged: bool = False


def make_ksp(A, P=None, rtol=DEFAULT_RTOL, ksp_type="cg", pc_type="gamg", max_it=None):
    """A KSP with operator A and preconditioner matrix P (default A).

    CG + GAMG by default; the PETSc options database overrides. (CG keeps
    PETSc's default, preconditioned, residual norm: see :data:`RESIDUAL_FACTOR`.)

    Wrap the creation and ksp.setUp() in :func:`petsc_options` to add options
    for one solve only (GAMG reads its level smoothers' options at set-up).
    """
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A, A if P is None else P)
    ksp.setType(ksp_type)
    ksp.getPC().setType(pc_type)
    ksp.setTolerances(rtol=rtol, max_it=max_it)
    ksp.setFromOptions()
    return ksp


@contextmanager
def petsc_options(options=None):
    """Temporarily set PETSc options ({"pc_type": "cholesky", "ksp_monitor": None}).

    Yields a list that, when the block ends, holds the options given here
    that PETSc never read (as "-name"), before they are taken out again.
    """
    db = PETSc.Options()
    options = {k.lstrip("-"): ("" if v is None else str(v)) for k, v in (options or {}).items()}
    refuse_crashing(options)   # before PETSc sees them (issue 45)
    saved = {k: db.getString(k) if db.hasName(k) else None for k in options}
    for k, v in options.items():
        db.setValue(k, v)
    unused = []
    try:
        yield unused
    finally:
        unused += unused_options(options)
        for k, v in saved.items():
            if v is None:
                db.delValue(k)
            else:
                db.setValue(k, v)


def reason_name(reason):
    names = {getattr(PETSc.KSP.ConvergedReason, n): n
             for n in dir(PETSc.KSP.ConvergedReason) if n.isupper()}
    return names.get(reason, str(reason))


class IndefinitePreconditioner(AmfeError):
    """CG met a negative curvature in the preconditioner (DIVERGED_INDEFINITE_PC)."""


ACCEPT_HINT = ("; to keep the numbers anyway, with a warning in the result, pass "
               "--accept-unconverged (accept_unconverged=True in Python)")


def check_solution(ksp, label, residual, pc_residual, accept=False):
    """Hold a finished solve to the convergence contract (:data:`RESIDUAL_FACTOR`).

    residual: the true relative residual ||b - A x|| / ||b||; pc_residual: a
    callable giving the same residual in the norm the KSP tests (called
    only when ``residual`` misses; collective like everything here, so every
    rank decides alike). Returns (warning, note): warning is None when the
    solve passes, else, with ``accept``, why it does not (without
    ``accept`` that is an AmfeError on every rank); note says why a solve
    above RESIDUAL_FACTOR x rtol passed (its own norm, or the rounding
    floor). A non-finite residual and an indefinite
    preconditioner (:class:`IndefinitePreconditioner`, which the caller may
    retry) are errors even with ``accept``.
    """
    reason = ksp.getConvergedReason()
    rtol, atol, dtol, max_it = ksp.getTolerances()
    its = ksp.getIterationNumber()
    how = f"{ksp.getType().upper()} solve with {ksp.getPC().getType()}"
    if reason == PETSc.KSP.ConvergedReason.DIVERGED_INDEFINITE_PC or not math.isfinite(residual):
        check_converged(ksp, label)
        raise AmfeError(f"{label}: the {how} gave a non-finite solution (true residual "
                        f"{residual}) after {its} iterations; check the bed and the options")
    # converged on the initial guess, within the contract of a loose rtol (a residual above it
    # is the contract's error below, which accept_unconverged may keep)
    if (reason > 0 and its == 0 and RESIDUAL_FACTOR * LOOSEST_RTOL < residual
            <= RESIDUAL_FACTOR * rtol):
        floor = pc_residual()[2]
        if residual > RESIDUAL_FACTOR * max(LOOSEST_RTOL, floor):
            raise AmfeError(
                f"{label}: the {how} stopped after 0 iterations ({reason_name(reason)} at rtol "
                f"{rtol:g}, atol {atol:g}) with the initial guess's true relative residual at "
                f"{residual:.2e}: nothing was solved, and the constants would be those of the "
                f"guess. The tolerance is too loose: give rtol {LOOSEST_RTOL:g} or less "
                f"(the loosest amfe homogenize accepts, docs/model.md section 5)")
    if reason <= 0:
        message = converged_message(ksp, label) + f"; true relative residual {residual:.2e}"
    elif residual <= RESIDUAL_FACTOR * rtol:
        return None, None
    else:
        in_norm, norm, floor = pc_residual()
        limit = RESIDUAL_FACTOR * max(rtol, floor)
        if min(residual, in_norm) <= limit:
            return None, (f"{label}: true relative residual {residual:.1e} "
                          f"({residual / rtol:.3g} x rtol), {in_norm:.1e} in the {norm} norm the "
                          f"KSP tests; rounding floor eps ||A|| ||x|| / ||b|| = {floor:.1e}")
        message = (f"{label}: the {how} stopped ({reason_name(reason)} after {its} "
                   f"iterations) with the true relative residual ||b - A x|| / ||b|| at "
                   f"{residual:.2e} ({in_norm:.2e} in the {norm} norm), above "
                   f"{RESIDUAL_FACTOR:g} x rtol = {RESIDUAL_FACTOR * rtol:.1e} (atol {atol:g}, "
                   f"max_it {max_it}): the constants would be wrong. Remove the options that "
                   "stop a solve early (-ksp_atol, -ksp_max_it, -ksp_type preonly with an "
                   "inexact preconditioner)")
    if accept:
        return message, None
    raise AmfeError(message + ACCEPT_HINT)


def converged_message(ksp, label):
    """What a KSP that stopped without converging says about itself."""
    reason = ksp.getConvergedReason()
    rtol, atol, dtol, max_it = ksp.getTolerances()
    return (f"{label}: the {ksp.getType().upper()} solve with {ksp.getPC().getType()} did not "
            f"converge: {reason_name(reason)} after {ksp.getIterationNumber()} iterations, "
            f"residual norm {ksp.getResidualNorm():.3e} (rtol {rtol:g}, max_it {max_it}). The "
            "frame may be ill-conditioned or a near-mechanism; try -ksp_monitor_true_residual, a "
            "direct solver (-ksp_type preonly -pc_type cholesky), or check the bed")


def check_converged(ksp, label):
    """Raise AmfeError (on every rank alike: the reason is collective) unless converged."""
    reason = ksp.getConvergedReason()
    if reason > 0:
        return
    indefinite = reason == PETSc.KSP.ConvergedReason.DIVERGED_INDEFINITE_PC
    raise (IndefinitePreconditioner if indefinite else AmfeError)(
        converged_message(ksp, label) + ".")

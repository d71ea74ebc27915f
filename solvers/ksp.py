"""KSP/PC set-up and the convergence check every solve goes through."""
from contextlib import contextmanager

from amfe.errors import AmfeError

DEFAULT_RTOL = 1e-8
"""Relative residual tolerance of the CG solves. The constants come from
reaction forces, whose error is about rtol times the condition-dependent
amplification; 1e-8 leaves them accurate to ~1e-7 relative or better on the
beds measured (see the benchmark), three orders below the spread between beds,
at about one extra GAMG iteration per decade."""


def make_ksp(PETSc, A, P=None, rtol=DEFAULT_RTOL, ksp_type="cg", pc_type="gamg", max_it=None):
    """A KSP with operator A and preconditioner matrix P (default A).

    CG + GAMG by default; the PETSc options database overrides.

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
def petsc_options(PETSc, options=None):
    """Temporarily set PETSc options ({"pc_type": "cholesky", "ksp_monitor": None})."""
    db = PETSc.Options()
    options = {k.lstrip("-"): ("" if v is None else str(v)) for k, v in (options or {}).items()}
    saved = {k: db.getString(k) if db.hasName(k) else None for k in options}
    for k, v in options.items():
        db.setValue(k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                db.delValue(k)
            else:
                db.setValue(k, v)


def reason_name(PETSc, reason):
    names = {getattr(PETSc.KSP.ConvergedReason, n): n
             for n in dir(PETSc.KSP.ConvergedReason) if n.isupper()}
    return names.get(reason, str(reason))


class IndefinitePreconditioner(AmfeError):
    """CG met a negative curvature in the preconditioner (DIVERGED_INDEFINITE_PC)."""


def check_converged(PETSc, ksp, label):
    """Raise AmfeError (on every rank alike: the reason is collective) unless converged."""
    reason = ksp.getConvergedReason()
    if reason > 0:
        return
    rtol, atol, dtol, max_it = ksp.getTolerances()
    indefinite = reason == PETSc.KSP.ConvergedReason.DIVERGED_INDEFINITE_PC
    raise (IndefinitePreconditioner if indefinite else AmfeError)(
        f"{label}: the {ksp.getType().upper()} solve with {ksp.getPC().getType()} did not converge: "
        f"{reason_name(PETSc, reason)} after {ksp.getIterationNumber()} iterations, residual norm "
        f"{ksp.getResidualNorm():.3e} (rtol {rtol:g}, max_it {max_it}). The frame may be "
        "ill-conditioned or a near-mechanism; try -ksp_monitor_true_residual, a direct solver "
        "(-ksp_type preonly -pc_type cholesky), or check the bed.")

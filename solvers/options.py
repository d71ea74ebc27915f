"""One call's PETSc options: in the options database for that call alone.

PETSc keeps one options database per process, and everything in amfe's solver
layer that reads an option (KSPSetFromOptions, GAMG's levels, amfe's own
``-amfe_*`` options, the solver choice) reads it there. A call of
:func:`~amfe.solvers.driver.homogenize_bed` or
:func:`~amfe.solvers.voxel.homogenize_voxel` runs inside :func:`call_options`:

- its ``petsc_args`` (and the command line's options, which belong to every
  call of the ``amfe`` command: :func:`amfe.solvers.petsc.init_petsc` records
  them) are set on entry and taken out on exit, also when the call fails, so
  that nothing of one call reaches the next (issue 45, item 3);
- options of PETSc's objects (``-ksp_*``, ``-pc_*``, ``-mg_*``, ``-mat*``,
  ``-amfe_*``, ...) that someone else put in the database (``petsc4py.init``,
  ``PETSc.Options().setValue``) are taken out for the call, restored after it,
  and named in one warning: amfe does not apply options it was not given;
- process-wide options (``-log_view``, ``-info``, ``-malloc_debug``, ...) are
  left as they are: PETSc reads them itself, at start-up or at the end;
- the call's own options that PETSc never read are its "never used" warning.

The per-solve ``ksp_options`` nest inside (:func:`amfe.solvers.ksp.petsc_options`).
Prefixes per KSP were considered: every reader of the database would then have
to ask under the prefix; taking the database back to a known state per call
gives the same isolation in one place. Not thread-safe, like PETSc's database.
"""
import logging
import re
from contextlib import contextmanager
from dataclasses import dataclass, field

from amfe.errors import AmfeError
from amfe.solvers.petsc import (
    READ_AT_FINALIZE,
    command_line_pairs,
    init_petsc,
    is_object_option,
    option_pairs,
    option_used,
)

LOG = logging.getLogger("amfe.solvers")

_ignored_warned = set()


@dataclass
class CallScope:
    """What :func:`call_options` found: own {name: value} (the call's options, the command
    line's included), given (the names of ``petsc_args``: their used flags start afresh),
    ignored {name: value} (object options set outside amfe, out of the database during the
    call)."""

    own: dict
    given: set
    ignored: dict = field(default_factory=dict)

    def unused(self):
        """The call's options PETSc has not read (so far), as "-name"."""
        return sorted(f"-{n}" for n in self.own
                      if n not in READ_AT_FINALIZE and option_used(n) is False)

    def ignored_warning(self, rank):
        """One line naming the options set outside amfe that this call did not apply, or None;
        rank 0 logs it the first time those names come up in this process."""
        if not self.ignored:
            return None
        shown = " ".join(f"-{n}" + (f" {v}" if v else "") for n, v in sorted(self.ignored.items()))
        line = (f"PETSc options set outside amfe (petsc4py.init or PETSc.Options) were not "
                f"applied: {shown}; give them to this call (petsc_options= in amfe.homogenize, "
                "SolveOptions.petsc_args, or the command line)")
        if rank == 0 and not set(self.ignored) <= _ignored_warned:
            LOG.warning(line)
        _ignored_warned.update(self.ignored)
        return line


#: A multigrid level smoother's KSP type (any prefix, any level, up or down).
LEVEL_KSP_TYPE = re.compile(r"(^|_)mg_levels(_\d+)?(_up|_down)?_ksp_type$")
#: GAMG's graph types that build from the matrix alone ("geo" needs the nodes' coordinates
#: of a 2-D scalar problem, PCSetCoordinates, which amfe does not give: PETSc error 77).
GAMG_TYPES = ("agg", "classical")


def refuse_crashing(options):
    """AmfeError for an option PETSc 3.18 cannot run with amfe's solvers, as a class.

    options: {name: value} (a dash allowed). A level smoother of PCMG/GAMG starts its
    up-sweep from the coarse correction, a nonzero initial guess, and a KSP of type
    preonly refuses one (KSPSolve_PREONLY, error 83), after which PETSc 3.18 crashes
    with SEGV in its clean-up: so every ``*mg_levels[_N][_up|_down]_ksp_type preonly``.
    And a ``pc_gamg_type`` other than :data:`GAMG_TYPES`; and ``-ksp_norm_type none`` on a
    Krylov KSP (no convergence test: it ran to max_it, 43 s, before the contract refused it).
    """
    for name, value in options.items():
        name, value = name.lstrip("-"), str("" if value is None else value).strip().lower()
        if LEVEL_KSP_TYPE.search(name) and value == "preonly":
            raise AmfeError(
                f"-{name} preonly is not supported: a multigrid level smoother starts from "
                "the coarse correction (a nonzero initial guess), which a preonly KSP refuses, "
                "and PETSc 3.18 then crashes; use richardson (one sweep of the level's "
                "preconditioner) or the default chebyshev")
        if name == "ksp_norm_type" and value == "none" and _ksp_type(options) != "preonly":
            raise AmfeError(
                "-ksp_norm_type none: a Krylov solve without a residual norm cannot test "
                "convergence and would run to its iteration limit before amfe's check refuses "
                "it; leave the norm to PETSc (the default), or use -ksp_type preonly with a "
                "direct -pc_type")
        if name.endswith("pc_gamg_type") and value not in GAMG_TYPES:
            raise AmfeError(
                f"-{name} {value}: amfe's GAMG takes {' or '.join(GAMG_TYPES)} (geo needs the "
                "nodes' coordinates of a 2-D scalar problem, which a frame or voxel model "
                "does not give)")


def _ksp_type(options):
    """The outer KSP's type: in ``options``, else in the database, else cg."""
    for name, value in options.items():
        if name.lstrip("-") == "ksp_type":
            return str(value).strip().lower()
    db = init_petsc().Options()
    return db.getString("ksp_type").lower() if db.hasName("ksp_type") else "cg"


@contextmanager
def call_options(args=()):
    """Set one call's PETSc options for the ``with`` block; yields a :class:`CallScope`.

    args: the call's PETSc options as a command line (["-ksp_rtol", "1e-6"]); the command
    line's options (:func:`amfe.solvers.petsc.command_line_pairs`) come first, ``args``
    override them. On exit the database is as it was on entry, error or not.
    """
    db = init_petsc().Options()
    before = {n: "" if v is None else v for n, v in db.getAll().items()}   # flags: ""

    given = dict(option_pairs(list(args)))
    own = {**dict(command_line_pairs()), **given}
    scope = CallScope(own, set(given), {n: v for n, v in before.items()
                                        if is_object_option(n) and n not in own})
    try:
        for name in scope.ignored:
            db.delValue(name)
        for name, value in own.items():
            if name in given and db.hasName(name):
                db.delValue(name)   # a fresh entry: PETSc's "used" flag starts at no
            if name in given or name not in before or before[name] != value:
                db.setValue(name, value)
        refuse_crashing(own)
        yield scope
    finally:
        changed = [n for n, v in own.items() if n in given or n not in before or before[n] != v]
        for name in changed:
            if db.hasName(name):
                db.delValue(name)
        for name, value in before.items():
            if name in changed or name in scope.ignored:
                db.setValue(name, value)

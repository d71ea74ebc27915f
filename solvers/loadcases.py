"""Every load case of a boundary condition on a distributed frame.

A boundary condition hands over its groups of load cases
(:class:`amfe.model.loadcase.Group`); each group gets one constrained operator
and one preconditioner set-up (:class:`amfe.solvers.operator.ConstrainedOperator`),
then one solve per case. The result is a :class:`LoadCaseSolutions`.
"""
import time
from dataclasses import dataclass, field, replace

import numpy as np

from amfe.errors import AmfeError
from amfe.model.averages import box_center
from amfe.solvers.assembly import local_block_rows, small_pages
from amfe.solvers.ksp import CaseSettings, IndefinitePreconditioner
from amfe.solvers.operator import ConstrainedOperator
from amfe.solvers.partition import row_ranges
from amfe.solvers.petsc import READ_AT_FINALIZE
from amfe.solvers.petsclib import PETSc
from amfe.solvers.progress import Progress

# GAMG's Chebyshev smoothers scale by an estimate of the largest eigenvalue of
# D^-1 A from 10 Krylov steps. Very stiff bonds among the prescribed particles
# (a* within ~1e-7 of the critical value) can make it too low: the smoother
# amplifies the top modes and CG stops with DIVERGED_INDEFINITE_PC. The retry
# estimates with 50 steps (measured: converges, 1e-10 from a direct solve):
# GAMG's estimate with smoothed aggregation, the smoothers' own without (the
# block path's -pc_gamg_agg_nsmooths 0).
ROBUST_ESTEIG = {"pc_gamg_esteig_ksp_max_it": 50, "mg_levels_esteig_ksp_max_it": 50}


@dataclass
class LoadCaseSolutions:
    """The solutions of every load case, in the order of the groups' cases.

    u: (cases, n, 6) on rank 0 (None elsewhere); moments: (cases, 3, 3) the
    reaction moments about ``center`` (the same on every rank); cases: the
    per-case :class:`~amfe.solvers.operator.CaseSolution` s (their ``u``
    dropped); setups: one :class:`~amfe.solvers.operator.SetupRecord` per
    group; block_seconds: the element blocks' time; notes: retries made.
    """

    u: np.ndarray
    moments: np.ndarray
    center: np.ndarray
    cases: list
    setups: list
    group_of_case: list
    block_seconds: float
    notes: list = field(default_factory=list)

    @property
    def names(self):
        return [c.name for c in self.cases]

    @property
    def iterations(self):
        return [c.iterations for c in self.cases]

    @property
    def residuals(self):
        return [c.residual for c in self.cases]

    @property
    def warnings(self):
        """Why accepted solves missed the convergence contract (accept_unconverged)."""
        return [c.warning for c in self.cases if c.warning]

    @property
    def unused_options(self):
        """Per-solve PETSc options (``ksp_options``) that PETSc never read, as "-name"."""
        return sorted({n for s in self.setups for n in s.unused_options})

    @property
    def cross(self):
        """Per group its (k, k) D_ij = x_i . r_j, or None (:mod:`amfe.solvers.correction`)."""
        return [s.cross for s in self.setups]

    @property
    def setup_seconds(self):
        return float(sum(s.setup_seconds for s in self.setups))

    @property
    def assembly_seconds(self):
        return self.block_seconds + float(sum(s.assembly_seconds for s in self.setups))

    @property
    def solve_seconds(self):
        return float(sum(c.seconds for c in self.cases))

    def diagnostics(self):
        """Per case: iterations, true residual, eigenvalue estimates, GAMG complexities."""
        return [{"case": c.name, "iterations": c.iterations, "residual": c.residual, **c.eig,
                 **self.setups[g].pc_complexity}
                for c, g in zip(self.cases, self.group_of_case)]


def solve_load_cases(frame, comm, groups, *, center=None, log=None, **settings):
    """Solve every group of load cases on ``frame``; returns :class:`LoadCaseSolutions`.

    ``settings``: the fields of :class:`~amfe.solvers.ksp.CaseSettings` (rtol, max_it,
    ksp_options, diagnose, accept_unconverged). ``log``: called with a progress line per
    operator and per case (on every rank; the caller decides who prints); a
    :class:`~amfe.solvers.progress.Progress` also gets the phases' starts and the time left
    on long solves. Raises AmfeError
    on every rank, also for a solve that misses the convergence contract
    (:func:`amfe.solvers.ksp.check_solution`) unless ``accept_unconverged``.
    """
    settings = CaseSettings(**settings)
    if not isinstance(log, Progress):   # today's lines alone
        log = Progress(log, 0, sum(len(g.names) for g in groups))
    ksp_options = settings.ksp_options
    size, rank = comm.getSize(), comm.getRank()
    ranges = row_ranges(frame.n_particles, size)
    r0, r1 = int(ranges[rank]), int(ranges[rank + 1])
    center = box_center(frame.centers) if center is None else center
    rows, block_seconds = [], 0.0

    def block_rows(last):
        """[this rank's block rows], made when missing; the last group's operator empties it."""
        nonlocal block_seconds
        if not rows:
            t0 = time.perf_counter()
            log.phase("blocks", f"assembly: the element blocks of {len(frame.bonds)} bonds")
            with small_pages():
                rows.append(local_block_rows(frame, r0, r1))
            log.done("blocks", "assembly: element blocks made")
            block_seconds += time.perf_counter() - t0
        return rows, rows.clear if last else None

    cases, setups, group_of_case, notes, us = [], [], [], [], []
    for g, group in enumerate(groups):
        last = g == len(groups) - 1
        try:
            c, rec = _solve_group(frame, comm, (r0, r1), block_rows(last), group, center,
                                  settings, log)
        except PETSc.Error as exc:
            # e.g. an option PETSc cannot use (-pc_type unknown); PETSc printed the details
            given = sorted(set(PETSc.Options().getAll()) - READ_AT_FINALIZE
                           | set(ksp_options or {}))
            raise AmfeError(f"PETSc stopped with {exc} while solving cases "
                            f"{', '.join(group.names)}; its message is above. "
                            + ("Check the PETSc options given "
                               f"({', '.join('-' + g for g in given)})."
                               if given else "No PETSc option was given: the frame may be "
                               "singular or its stiffness out of range; check the bed.")) from None
        except IndefinitePreconditioner as exc:
            if "pc_gamg_esteig_ksp_max_it" in (ksp_options or {}):
                raise
            notes.append(f"cases {', '.join(group.names)}: {str(exc).split(':')[0]} met an "
                         "indefinite preconditioner; set up again with "
                         "-pc_gamg_esteig_ksp_max_it 50 -mg_levels_esteig_ksp_max_it 50")
            robust = replace(settings, ksp_options={**(ksp_options or {}), **ROBUST_ESTEIG})
            c, rec = _solve_group(frame, comm, (r0, r1), block_rows(last), group, center,
                                  robust, log)
        for case in c:
            us.append(case.u)
            case.u = None
            if case.note:
                notes.append(case.note)
        cases += c
        setups.append(rec)
        group_of_case += [g] * len(c)
    return LoadCaseSolutions(u=np.array(us) if rank == 0 else None,
                             moments=np.array([c.moment for c in cases]), center=center,
                             cases=cases, setups=setups, group_of_case=group_of_case,
                             block_seconds=block_seconds, notes=notes)


def _solve_group(frame, comm, part, rows, group, center, settings, log):
    """part: this rank's particle rows (r0, r1); rows: ([block rows], release or None):
    with release, the operator drops the block rows (about a third of the matrix's
    memory) once its matrices are made; settings: a CaseSettings; log: a
    :class:`~amfe.solvers.progress.Progress`."""
    held, release = rows
    log.phase("operator", f"operator for {', '.join(group.names)}: assembling the matrix, "
              "then setting up the preconditioner")
    op = ConstrainedOperator(frame, comm, *part, held[0], group, release=release,
                             **vars(settings))
    try:
        rec = op.record
        log(f"operator for {', '.join(group.names)}: "
            f"assembled in {rec.assembly_seconds:.2f} s, "
            f"{rec.pc_type} set up in {rec.setup_seconds:.2f} s")
        log.phase("cases", f"load case(s) {', '.join(group.names)}: solving")
        live = log.live(rec.path)   # long solves: each case as it is solved one at a time
        cases = op.solve_all(center, group.guesses,
                             progress=(log.iteration, live) if log.long else None)
        solved = len(log.case_seconds) + len(cases)
        for case in cases if rec.path == "block" or live is None else ():  # the block's at once
            log.case(case, rec.path, solved=solved)
        return cases, rec
    finally:
        op.destroy()

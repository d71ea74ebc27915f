"""One group's constrained operator: built once, then one solve per load case.

A group (:class:`amfe.model.loadcase.Group`) is a set of load cases that
prescribe the same DOFs. :class:`ConstrainedOperator` assembles the frame's
matrix, imposes the prescribed DOFs with MatZeroRowsColumns (identity rows and
columns that keep their own diagonal entry, the values lifted into the
right-hand sides), which keeps the AIJ block size 6 and the near null space
that GAMG needs, sets the preconditioner up once, and then solves each case
(:meth:`ConstrainedOperator.solve`). Reactions come from the unconstrained
rows of the constrained particles' translations (docs/model.md, section 5).

CG multiplies with a symmetric-block (SBAIJ) copy of the constrained matrix:
CG and the fine-level smoother are bound by MatMult's memory traffic, and the
upper 6x6 blocks with one index per block move fewer bytes than AIJ
(docs/benchmarks.md, "Figures quoted in the code").
GAMG is built from the AIJ matrix (it cannot use (S)BAIJ in PETSc 3.18). The
PETSc option -amfe_operator_type aij turns the copy off; the block path
(:meth:`ConstrainedOperator.solve_all`) needs none, as its products use AIJ.
"""
import time
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.model.averages import bagi_stress
from amfe.solvers.adjoint import strain_cross
from amfe.solvers.assembly import aij_from_blocks, sbaij_operator
from amfe.solvers.blocksolve import (
    block_path_applies,
    block_path_expected,
    solve_block,
    with_block_defaults,
)
from amfe.solvers.correction import takes_correction
from amfe.solvers.ksp import CaseSettings, check_solution, make_ksp, petsc_options
from amfe.solvers.nullspace import near_nullspace, orthonormal_nullspace
from amfe.solvers.petsclib import PETSc

AMFE_OPTIONS = ("amfe_operator_type", "amfe_block", "amfe_correction", "amfe_strain_adjoint")
"""amfe's own PETSc options (docs/model.md, section 5)."""


@dataclass
class SetupRecord:
    """What building one group's operator cost and chose.

    assembly_seconds, setup_seconds [s]; ksp_type, pc_type, rtol, norm_type
    (the residual norm the KSP tests) as PETSc resolved them (command-line
    options included); pc_complexity: GAMG's level sizes and complexities
    when diagnosing (else empty); unused_options: options of this operator's
    ``ksp_options`` that PETSc never read.
    """

    assembly_seconds: float
    setup_seconds: float
    ksp_type: str
    pc_type: str
    rtol: float
    norm_type: str = ""
    pc_complexity: dict = field(default_factory=dict)
    unused_options: list = field(default_factory=list)
    path: str = "one at a time"  # or "block" (ConstrainedOperator.solve_all)
    cross: np.ndarray = None  # D_ij = x_i . r_j of the group's solutions (solvers/correction.py)
    strain_cross: np.ndarray = None  # G_mj = z_m . r_j, the strain's adjoints (solvers/adjoint.py)
    adjoint_iterations: list = None
    adjoint_seconds: float = 0.0


@dataclass
class CaseSolution:
    """One load case's solution.

    u: (n, 6) DOFs on rank 0 (None elsewhere, or when not gathered), in the
    frame's units; moment: (3, 3) sum over constrained particles of
    f (x) (x - center), summed over ranks; residual: true relative residual
    ||b - A x|| / ||b||; eigenvalue estimates only when diagnosing; warning:
    why the solve missed the convergence contract, when it was accepted anyway;
    note: when the KSP's own norm decided it (see :func:`~amfe.solvers.ksp.check_solution`).
    """

    name: str
    iterations: int
    residual: float
    seconds: float
    moment: np.ndarray
    u: np.ndarray = None
    eig: dict = field(default_factory=dict)
    warning: str = None
    note: str = None


class ConstrainedOperator:
    """The constrained operator of one group on a row block [r0, r1) of particles.

    Build it once (the assembly and the preconditioner set-up), call
    :meth:`solve` for each case, then :meth:`destroy`. Collective on ``comm``.
    block_rows: :func:`amfe.solvers.assembly.local_block_rows`; release: a
    callable that drops the caller's reference to them, called once the
    matrices are made (None: the caller keeps them).
    """

    def __init__(self, frame, comm, r0, r1, block_rows, group, *, release=None, **settings):
        s = CaseSettings(**settings)   # rtol, max_it, ksp_options, diagnose, accept_unconverged
        rtol, max_it, ksp_options, diagnose = s.rtol, s.max_it, s.ksp_options, s.diagnose
        self.comm, self.r0, self.r1 = comm, r0, r1
        self.frame, self.group, self.diagnose = frame, group, diagnose
        self.accept_unconverged = s.accept_unconverged
        n, nloc = frame.n_particles, r1 - r0
        t0 = time.perf_counter()
        A = aij_from_blocks(comm, n, r0, r1, *block_rows)
        fixed_loc = group.fixed[r0:r1]
        dofs = (np.flatnonzero(fixed_loc.ravel()) + 6 * r0).astype(PETSc.IntType)
        self.held = np.flatnonzero(fixed_loc.any(axis=1)) + r0  # particles with a reaction
        rdofs = (6 * self.held[:, None] + np.arange(3)).ravel().astype(PETSc.IntType)
        self._isrow = PETSc.IS().createGeneral(rdofs, comm=comm)
        self._iscol = PETSc.IS().createStride(6 * nloc, first=6 * r0, step=1, comm=comm)
        self.A_r = A.createSubMatrix(self._isrow, self._iscol)  # unconstrained rows: reactions
        self._constrain(A, group, fixed_loc, dofs)
        x = frame.centers
        A.setNearNullSpace(near_nullspace(A, x[r0:r1], x.mean(axis=0)))
        with petsc_options(ksp_options):  # a direct solve sets amfe_operator_type aij
            aij_only = PETSc.Options().getString("amfe_operator_type", "sbaij") == "aij"
            self.block_option = PETSc.Options().getString("amfe_block", "yes")
            self.correct_option = PETSc.Options().getString("amfe_correction", "yes")
            block = block_path_expected(len(group.values), self.block_option, diagnose)
            # the block path's GAMG defaults also when diagnosing (one case at a time), so that
            # --diagnose describes the preconditioner of the run without it (issue 45)
            defaults = block or block_path_expected(len(group.values), self.block_option, False)
        if self.correct_option not in ("yes", "no"):  # refused before the set-up's cost
            raise AmfeError(f"-amfe_correction {self.correct_option!r}: give yes (the "
                            "second-order averages, the default) or no")
        if defaults:  # the block path multiplies with AIJ only (block), and has its GAMG defaults
            smoothed = group.smoothed_aggregation and rtol <= group.smoothed_rtol_max
            ksp_options = with_block_defaults(ksp_options, smoothed,
                                              comm.getSize())
        A_op = A if aij_only or block else sbaij_operator(comm, n, r0, r1, *block_rows,
                                                          fixed=group.fixed)
        if release is not None:  # the caller's last reference: GAMG's set-up reuses the memory
            release()
        del block_rows
        self.nullspace = None
        if group.null_modes is not None:
            self.nullspace = orthonormal_nullspace(A, group.null_modes[:, r0:r1])
            A.setNullSpace(self.nullspace)
            A_op.setNullSpace(self.nullspace)
        self.A, self.A_op = A, A_op
        t_assembly = time.perf_counter() - t0
        with petsc_options(ksp_options) as unused:
            # read above, in another setting of the options: mark them used
            for name in AMFE_OPTIONS:
                PETSc.Options().getString(name, "")
            ksp = make_ksp(A_op, A, rtol=rtol, max_it=max_it)
            if diagnose:
                ksp.setComputeEigenvalues(True)
            t0 = time.perf_counter()
            ksp.setUp()
            t_setup = time.perf_counter() - t0
        self.ksp = ksp
        self.record = SetupRecord(t_assembly, t_setup, ksp.getType(), ksp.getPC().getType(),
                                  float(ksp.getTolerances()[0]), norm_name(ksp),
                                  pc_complexity(ksp) if diagnose else {}, unused)
        self._r = A.createVecLeft()
        self._f = self.A_r.createVecLeft()
        self._scatter, self._u0 = PETSc.Scatter.toZero(self._r)

    def _constrain(self, A, group, fixed_loc, dofs):
        """Impose the prescribed DOFs ``dofs`` on A, with every case's right-hand side.

        Lift every case's prescribed values into its right-hand side while A
        is still unconstrained (b = -A x0 on the free rows), plus any applied
        forces (SUBC, periodic; their entries on fixed rows are overwritten below).
        """
        r0, r1 = self.r0, self.r1
        self._x0, self._b = [], []
        for k, values in enumerate(group.values):
            x0 = A.createVecRight()
            x0.setArray(np.where(fixed_loc, values[r0:r1], 0.0).ravel())
            b = A.createVecLeft()
            A.mult(x0, b)
            b.scale(-1.0)
            if group.forces is not None:
                b.getArray()[:] += group.forces[k][r0:r1].ravel()
            self._x0.append(x0)
            self._b.append(b)
        # A prescribed DOF keeps its own diagonal entry on its identity row: one
        # scale for all of them (say the mean diagonal) lets a few very stiff bonds
        # dominate ||b||, and rtol * ||b|| then no longer controls the free rows.
        diag = A.getDiagonal()
        A.zeroRowsColumns(dofs, diag=1.0)
        self._local_dofs = dofs - 6 * r0
        self._dvals = diag.getArray()[self._local_dofs].copy()
        d = A.getDiagonal()
        d.getArray()[self._local_dofs] = self._dvals
        A.setDiagonal(d)
        d.destroy()
        diag.destroy()
        for x0, b in zip(self._x0, self._b):
            b.getArray()[self._local_dofs] = self._dvals * x0.getArray()[self._local_dofs]

    def solve(self, k, center, guess=None, gather=True, keep=None):
        """Solve the group's case ``k``; returns a :class:`CaseSolution`.

        center (3,): the point the reaction moments are taken about;
        guess: optional (n, 6) initial guess (ignored by direct solvers);
        keep: a list that receives copies of (x, b - A x) (for :meth:`solve_all`'s
        correction; the caller destroys them).
        """
        ksp, r0, r1 = self.ksp, self.r0, self.r1
        name, b = self.group.names[k], self._b[k]
        u = self.A.createVecRight()
        # (a direct solve, KSP preonly, takes no initial guess)
        use_guess = guess is not None and ksp.getType() != "preonly"
        ksp.setInitialGuessNonzero(use_guess)
        if use_guess:
            u.setArray(guess[r0:r1].ravel())
        t0 = time.perf_counter()
        ksp.solve(b, u)
        seconds = time.perf_counter() - t0
        # the prescribed DOFs' exact values (an iterate carries rtol-sized errors there)
        u.getArray()[self._local_dofs] = self._x0[k].getArray()[self._local_dofs]
        self.A.mult(u, self._r)
        self._r.aypx(-1.0, b)
        bnorm = b.norm()  # zero when a case prescribes nothing but zeros
        residual = float(self._r.norm() / bnorm if bnorm > 0 else self._r.norm())
        warning, note = check_solution(ksp, f"load case {name}", residual,
                                       lambda: self._residual_in_ksp_norm(b),
                                       accept=self.accept_unconverged)
        eig = {}
        if self.diagnose:
            smax, smin = ksp.computeExtremeSingularValues()
            eig = dict(eig_max=float(smax), eig_min=float(smin),
                       condition=float(smax / smin) if smin > 0 else float("inf"))
        moment, u_root = self._reactions(u, center, gather)
        iterations = int(ksp.getIterationNumber())
        if keep is not None:
            keep.append((u.copy(), self._r.copy()))
        u.destroy()
        return CaseSolution(name, iterations, residual, seconds, moment, u_root, eig, warning,
                            note)

    def solve_all(self, center, guesses=None, gather=True, progress=None):
        """Solve every case of the group; a list of :class:`CaseSolution`, in its order.

        Two or more cases with CG + GAMG (Chebyshev/Jacobi levels) go through
        one block CG that shares every product and V-cycle
        (:func:`amfe.solvers.blocksolve.solve_block`, the same iterations and
        solutions); -amfe_block no, a single case, diagnosis or another
        solver solve one at a time (:meth:`solve`). guesses: optional list of
        (n, 6) initial guesses, one per case. ``record.path`` says which ran. progress: None or
        (the block CG's monitor, :func:`amfe.solvers.blocksolve.solve_block`; a callable
        given each case as it is solved one at a time, or None).
        """
        monitor, solved = progress or (None, None)
        names, r0, r1 = self.group.names, self.r0, self.r1
        correct = self._corrects()
        cols, info = None, {}
        if block_path_applies(self.ksp, len(names), self.block_option, self.diagnose):
            X0 = None if guesses is None else [g[r0:r1].ravel() for g in guesses]
            fixed = (self._local_dofs,
                     np.stack([x.getArray()[self._local_dofs] for x in self._x0], axis=1))
            cols = solve_block(self.ksp, self._b, X0, info=info, prescribed=fixed,
                               monitor=monitor)
        if cols is None:
            keep = [] if correct else None
            out = []
            for k in range(len(names)):
                out.append(self.solve(k, center, None if guesses is None else guesses[k],
                                      gather, keep))
                if solved is not None:
                    solved(out[-1])
            if correct:
                self.record.cross = np.array([[xi.dot(rj) for _, rj in keep] for xi, _ in keep])
                self._strain_adjoint([u for u, _ in keep])
                for pair in keep:
                    for v in pair:
                        v.destroy()
            return out
        self.record.path = "block"
        checks = {}  # the contract of solve(); an indefinite preconditioner first (the retry)
        for k in sorted(range(len(cols)), key=lambda k: not cols[k].indefinite):
            checks[k] = check_solution(cols[k].ksp, f"load case {names[k]}",
                                       cols[k].residual, lambda: self._column_norm(k, cols[k].u),
                                       accept=self.accept_unconverged)
        if correct:
            self._strain_adjoint([col.u for col in cols])
        out = []
        for k, (name, col) in enumerate(zip(names, cols)):
            moment, u_root = self._reactions(col.u, center, gather)
            out.append(CaseSolution(name, col.iterations, col.residual, col.seconds, moment,
                                    u_root, {}, *checks[k]))
            col.u.destroy()
        self.record.cross = info.get("cross") if correct else None
        return out

    def _strain_adjoint(self, us):
        """The strain's adjoint cross products G into the record, where the group has loads."""
        if self.group.adjoint is not None:
            rec = self.record
            rec.strain_cross, rec.adjoint_iterations, rec.adjoint_seconds = strain_cross(self, us)

    def _corrects(self):
        """Whether this group's cross products D are computed (-amfe_correction, default yes)."""
        return self.correct_option == "yes" and takes_correction(self.group)

    def _column_norm(self, k, u):
        """:meth:`_residual_in_ksp_norm` of case k's block-path solution ``u``."""
        self.A.mult(u, self._r)
        self._r.aypx(-1.0, self._b[k])
        return self._residual_in_ksp_norm(self._b[k], u)

    def _reactions(self, u, center, gather):
        """(moment (3, 3) about ``center``, summed over ranks; u (n, 6) on rank 0 or None)."""
        self.A_r.mult(u, self._f)
        local = bagi_stress(self._f.getArray().reshape(-1, 3), self.frame.centers[self.held],
                            center, 1.0)
        moment = self.comm.tompi4py().allreduce(local)
        u_root = None
        if gather:
            self._scatter.scatter(u, self._u0, addv=PETSc.InsertMode.INSERT,
                                  mode=PETSc.ScatterMode.FORWARD)
            if self.comm.getRank() == 0:
                u_root = self._u0.getArray().reshape(-1, 6).copy()
        return moment, u_root

    def _residual_in_ksp_norm(self, b, x=None):
        """(true relative residual in the norm the KSP tests, that norm's name, rounding floor).

        self._r holds r = b - A x (x: the KSP's solution unless given). Preconditioned (and
        none: preonly): ||B r|| / ||B b||; natural: sqrt(r.Br / b.Bb); unpreconditioned:
        ||r|| / ||b||. The floor is the normwise backward-error bound
        eps ||A||_F ||x|| / ||b||: no solve in double precision can promise
        a smaller relative residual.
        """
        pc, r = self.ksp.getPC(), self._r
        norm = norm_name(self.ksp)
        bnorm = b.norm() or 1.0  # zero when the case prescribes only zeros
        floor = (np.finfo(float).eps * self.A.norm(PETSc.NormType.FROBENIUS)
                 * (self.ksp.getSolution() if x is None else x).norm() / bnorm)
        if norm == "unpreconditioned":
            return r.norm() / bnorm, norm, floor
        z, zb = r.duplicate(), b.duplicate()
        pc.apply(r, z)
        pc.apply(b, zb)
        if norm == "natural":
            value = (abs(r.dot(z)) / (abs(b.dot(zb)) or 1.0)) ** 0.5
        else:
            value, norm = z.norm() / (zb.norm() or 1.0), "preconditioned"
        z.destroy()
        zb.destroy()
        return float(value), norm, float(floor)

    def destroy(self):
        objs = [self.ksp, self.A_op, self.A, self.A_r, self._isrow, self._iscol,
                self._scatter, self._u0, self._r, self._f, *self._x0, *self._b]
        if self.nullspace is not None:
            objs.append(self.nullspace)
        seen = set()
        for obj in objs:
            if id(obj) not in seen:  # A_op may be A
                seen.add(id(obj))
                obj.destroy()


def norm_name(ksp):
    """The residual norm ``ksp`` tests: "unpreconditioned", "preconditioned", "natural", "none"."""
    names = {getattr(PETSc.KSP.NormType, n): n.lower() for n in
             ("NONE", "PRECONDITIONED", "UNPRECONDITIONED", "NATURAL")}
    return names.get(ksp.getNormType(), str(ksp.getNormType()))


def pc_complexity(ksp):
    """GAMG/MG grid and operator complexity and level sizes (empty for other PCs)."""
    pc = ksp.getPC()
    if pc.getType() not in ("gamg", "mg"):
        return {}
    rows, nnz = [], []
    for level in range(pc.getMGLevels()):
        P = pc.getMGSmoother(level).getOperators()[1]
        rows.append(int(P.getSize()[0]))
        nnz.append(int(P.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]))
    return {"levels": rows[::-1],
            "grid_complexity": float(sum(rows) / rows[-1]),
            "operator_complexity": float(sum(nnz) / nnz[-1])}

"""GAMG's V-cycle applied to k right-hand sides at once, on GAMG's own hierarchy.

PETSc 3.18 applies PCMG/GAMG to a block column by column (PCMatApply: 72
MatMults for 6 columns), so six load cases read every level's matrix six times
per sweep. :class:`BlockVCycle` takes a set-up PCGAMG (or PCMG) with Chebyshev
+ Jacobi smoothers and does the same multiplicative V-cycle on (rows, k)
blocks, with every product a k-column product (:mod:`amfe.solvers.maij`):

- level l > 0: Chebyshev of degree = the smoother's max_it, preconditioned by
  the inverse diagonal of the level matrix, on the target interval GAMG chose;
  pre-smoothing from zero, restriction by P_l^T, the coarser cycle,
  interpolation by P_l, post-smoothing from that guess;
- level 0: GAMG's own coarse solver (a direct LU) column by column. The
  coarse grid has a few dozen rows: 0.05 ms a column on 2 ranks, where a
  Cholesky factor gathered on every rank took 12 ms for six columns (the
  gather) and differed from PETSc's shifted LU on singular coarse grids.

PETSc prints the Chebyshev targets with six digits (KSPView) and has no getter
in 3.18, so the targets read from the view differ from PETSc's by up to 5e-7
relative, and a block V-cycle column from PCApply by about 1e-6
(:meth:`BlockVCycle.check`; a larger difference means a preconditioner the
block cycle does not reproduce). With ``pin=True`` the targets read are set
back on PETSc's smoothers (KSPChebyshevSetEigenvalues); both then apply the
same preconditioner to 1e-15 (the tests use this; it would change the
one-at-a-time path, so the solver does not).

Every product uses the level's preconditioner matrix (AIJ, the matrix GAMG
was built from); on the fine level that is the constrained AIJ matrix, whose
values equal the SBAIJ copy's (docs/model.md, section 5).
"""
import os
import re
import tempfile

import numpy as np

from amfe.errors import AmfeError
from amfe.solvers.maij import block_product, set_chebyshev_targets
from amfe.solvers.petsclib import PETSc


class BlockUnsupported(AmfeError):
    """The preconditioner is not one the block V-cycle reproduces (use one at a time)."""


def view_text(obj):
    """The ASCII view of a PETSc object, as a string on every rank (collective)."""
    mpi = obj.getComm().tompi4py()
    name = None
    if mpi.rank == 0:
        fd, name = tempfile.mkstemp(prefix="amfe_view_", suffix=".txt")
        os.close(fd)
    name = mpi.bcast(name, root=0)
    viewer = PETSc.Viewer().createASCII(name, comm=obj.getComm())
    obj.view(viewer)
    viewer.destroy()
    text = None
    if mpi.rank == 0:
        with open(name) as f:
            text = f.read()
        os.unlink(name)
    return mpi.bcast(text, root=0)


_NUM = r"([-+.\deE]+)"


def level_smoothers(pc):
    """[(emin, emax)] Chebyshev targets of levels 1..L-1, from the PC's view.

    Raises BlockUnsupported unless the PC is a multiplicative V-cycle (one per
    apply) whose levels all smooth with Chebyshev + point Jacobi, the same
    smoother up and down.
    """
    if pc.getType() not in ("gamg", "mg"):
        raise BlockUnsupported(f"the preconditioner is {pc.getType()}, not GAMG")
    nlev = pc.getMGLevels()
    if nlev < 2:   # -pc_gamg_threshold 0.5 on a small frame: no V-cycle to run on a block
        raise BlockUnsupported(f"GAMG built {nlev} level: its coarse solve is the whole solve")
    text = view_text(pc)
    if not re.search(rf"type is MULTIPLICATIVE, levels={nlev} cycles=v", text) or \
            not re.search(r"Cycles per PCApply=1\b", text):
        raise BlockUnsupported("the multigrid cycle is not one multiplicative V-cycle")
    sections = re.split(r"Down solver \(pre-smoother\) on level (\d+) -+", text)[1:]
    targets = []
    for level, body in zip(sections[::2], sections[1::2]):
        m = re.search(rf"eigenvalue targets used: min {_NUM}, max {_NUM}", body)
        same = "Up solver (post-smoother) same as down solver" in body
        if (m is None or not same or "type: chebyshev" not in body
                or not re.search(r"type: jacobi\s+type DIAGONAL", body)):
            raise BlockUnsupported(f"level {level} does not smooth with Chebyshev + Jacobi "
                                   "(the same up and down)")
        targets.append((float(m.group(1)), float(m.group(2))))
    if len(targets) != nlev - 1 or any(not 0 < lo < hi for lo, hi in targets):
        raise BlockUnsupported("the Chebyshev targets could not be read from GAMG's view")
    return targets


class CoarseSolve:
    """GAMG's coarse KSP applied to each column of a block."""

    def __init__(self, ksp):
        self.ksp = ksp
        self.x, self.b = ksp.getOperators()[1].createVecs()

    def solve(self, B, X):
        for j in range(B.shape[1]):
            self.b.setArray(B[:, j])
            self.ksp.solve(self.b, self.x)
            X[:, j] = self.x.getArray()

    def destroy(self):
        self.x.destroy()
        self.b.destroy()


class _Level:
    """One smoothed level: its k-column products, Jacobi, Chebyshev coefficients, work blocks."""

    def __init__(self, pc, l, k, targets, backend):
        smoother = pc.getMGSmoother(l)
        M = smoother.getOperators()[1]
        d = M.getDiagonal()
        diag = d.getArray().copy()
        d.destroy()
        self.dinv = np.where(diag != 0, 1.0 / np.where(diag != 0, diag, 1.0), 1.0)[:, None]
        self.emin, self.emax = targets
        self.degree = int(smoother.getTolerances()[3])
        self.rows = M.getSize()[0]
        self.nnz = M.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]
        self.A = block_product(M, k, backend)
        P = pc.getMGInterpolation(l)
        self.p_nnz = P.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]
        self.P = block_product(P, k, backend)
        m = M.getLocalSize()[0]
        self.R, self.D, self.T = (np.zeros((m, k)) for _ in range(3))

    def smooth(self, B, X, zero_guess, residual):
        """Chebyshev on A X = B (Saad, Iterative Methods, algorithm 12.1, Jacobi-preconditioned).

        zero_guess: start from X = 0 (else from X); residual: leave B - A X in R.
        Each numpy pass over a block costs about a ninth of a product with
        the level matrix, so the updates are written to make as few as possible.
        """
        R, D, T, dinv = self.R, self.D, self.T, self.dinv
        theta, delta = 0.5 * (self.emax + self.emin), 0.5 * (self.emax - self.emin)
        sigma = theta / delta
        rho = 1.0 / sigma
        if not zero_guess:
            np.subtract(B, self.A.mult(X, T), out=R)
        for i in range(self.degree):
            first = i == 0 and zero_guess  # the residual is B, X is D
            if i == 0:
                np.multiply(B if zero_guess else R, dinv * (1.0 / theta), out=D)
            else:
                rho_new = 1.0 / (2.0 * sigma - rho)
                D *= rho_new * rho
                D += np.multiply(R, dinv * (2.0 * rho_new / delta), out=T)
                rho = rho_new
            if first:
                X[:] = D
            else:
                X += D
            if i < self.degree - 1 or residual:
                self.A.mult(D, T)
                if first:
                    np.subtract(B, T, out=R)
                else:
                    R -= T

    def destroy(self):
        self.A.destroy()
        self.P.destroy()


class BlockVCycle:
    """GAMG's V-cycle for (rows, k) blocks; see the module docstring.

    pc: a set-up PCGAMG/PCMG; k: the number of columns; backend: the block
    products' ("auto", "maij" or "dense", :func:`amfe.solvers.maij.block_product`).
    pin: set the targets read on PETSc's smoothers too (see the module
    docstring). Raises BlockUnsupported for a preconditioner it cannot
    reproduce. Collective on the PC's communicator.
    """

    def __init__(self, pc, k, backend="auto", pin=False):
        targets = level_smoothers(pc)
        self.pc, self.k = pc, k
        self.coarse = CoarseSolve(pc.getMGCoarseSolve())
        m0 = self.coarse.b.getLocalSize()
        self.levels = []
        for l, t in enumerate(targets, start=1):
            if pin:
                set_chebyshev_targets(pc.getMGSmoother(l), *t)
            self.levels.append(_Level(pc, l, k, t, backend))
        # (B, X) blocks of each coarser level's correction; the finest level uses the caller's
        self._blocks = [(np.zeros((m0, k)), np.zeros((m0, k)))]
        self._blocks += [(np.zeros_like(lev.R), np.zeros_like(lev.R)) for lev in self.levels[:-1]]
        self.fine = self.levels[-1].A

    @property
    def scratch(self):
        """A fine-level (m, k) block the caller may use between cycles (a cycle overwrites it)."""
        return self.levels[-1].T

    def apply(self, B, X):
        """X = V-cycle(B) for an (m, k) block of the finest level's local rows; returns X."""
        self._cycle(len(self.levels), B, X)
        return X

    def _cycle(self, l, B, X):
        if l == 0:
            self.coarse.solve(B, X)
            return
        lev = self.levels[l - 1]
        Bc, Xc = self._blocks[l - 1]
        lev.smooth(B, X, zero_guess=True, residual=True)
        lev.P.mult_transpose(lev.R, Bc)
        self._cycle(l - 1, Bc, Xc)
        X += lev.P.mult(Xc, lev.T)
        lev.smooth(B, X, zero_guess=False, residual=False)

    def check(self, b, z_block, project=None):
        """Max relative difference of a block column ``z_block`` (m,) from PCApply(b).

        project: applied in place to PCApply's (m, 1) result first (the null
        space removal that ``z_block`` had).
        """
        z = b.duplicate()
        self.pc.apply(b, z)
        zc = z.getArray().copy()[:, None]
        z.destroy()
        if project is not None:
            project(zc)
        mpi = b.getComm().tompi4py()
        diff = max(mpi.allgather(float(np.abs(zc[:, 0] - z_block).max(initial=0.0))))
        scale = max(mpi.allgather(float(np.abs(zc).max(initial=0.0))))
        return diff / scale if scale > 0 else diff

    def describe(self):
        """Per level, fine to coarse: rows, nonzeros, degree, Chebyshev targets."""
        return [{"rows": lev.rows, "nnz": lev.nnz, "degree": lev.degree, "emin": lev.emin,
                 "emax": lev.emax} for lev in reversed(self.levels)]

    def products_per_cycle(self):
        """[(matrix nonzeros, number of k-column products)] of one V-cycle, all levels.

        2 x degree with each level matrix (pre-smoothing with the residual,
        post-smoothing with its start), and P^T, P once each.
        """
        out = []
        for lev in self.levels:
            out += [(lev.nnz, 2 * lev.degree), (lev.p_nnz, 2)]
        return out

    def destroy(self):
        for lev in self.levels:
            lev.destroy()
        self.coarse.destroy()

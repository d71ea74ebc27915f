"""Kinematic uniform boundary conditions: six macro-strains on one operator.

Boundary particles get the translation u = eps (x - x_c); their rotations and
all other DOFs stay free. The prescribed translations are imposed with
MatZeroRowsColumns (identity rows and columns, the prescribed values lifted
into each right-hand side), which keeps the AIJ block size 6 and the
near null space, so one GAMG set-up serves all six solves. PETSc option
-amfe_operator_type aij|sbaij (default sbaij) picks the storage of the
operator CG multiplies with; the preconditioner is always built from AIJ.
"""
import time

import numpy as np

from amfe.homogenize import bagi_stress, boundary_particles, box_center, unit_strains
from .assembly import aij_from_blocks, local_block_rows, sbaij_operator
from .ksp import DEFAULT_RTOL, check_converged, make_ksp, petsc_options
from .nullspace import near_nullspace
from .partition import row_ranges

CASE_NAMES = ("xx", "yy", "zz", "yz", "xz", "xy")


def solve_kubc(PETSc, frame, comm, rtol=DEFAULT_RTOL, max_it=None, ksp_options=None):
    """Solve the six KUBC load cases of ``frame`` (non-dimensional units).

    Returns a dict, identical on every rank except where noted:
      u (6, n, 6): DOFs of every particle per case (rank 0 only; None elsewhere)
      moments (6,3,3): sum over boundary particles of f (x) (x - x_c) [force*length]
      center (3,), boundary (n,) bool, iterations [6], residuals [6] (true,
      relative), setup_seconds, solve_seconds, case_seconds [6], assembly_seconds,
      ksp_type, pc_type, rtol.
    ksp_options: extra PETSc options for this solve only (see solvers.ksp.make_ksp).
    """
    size, rank = comm.getSize(), comm.getRank()
    ranges = row_ranges(frame.n_particles, size)
    r0, r1 = int(ranges[rank]), int(ranges[rank + 1])

    t0 = time.perf_counter()
    block_rows = local_block_rows(frame, r0, r1)
    A = aij_from_blocks(PETSc, comm, frame.n_particles, r0, r1, *block_rows)
    t_assembly = time.perf_counter() - t0

    x = frame.centers
    center = box_center(x)
    boundary = boundary_particles(x, frame.radii)
    local_b = np.flatnonzero(boundary[r0:r1]) + r0
    bdofs = (6 * local_b[:, None] + np.arange(3)).ravel().astype(PETSc.IntType)

    isrow = PETSc.IS().createGeneral(bdofs, comm=comm)
    iscol = PETSc.IS().createStride(6 * (r1 - r0), first=6 * r0, step=1, comm=comm)
    A_b = A.createSubMatrix(isrow, iscol)  # boundary translation rows: the reactions

    # Prescribed translations of all six cases, and their lifting into the RHS.
    eps = unit_strains()
    xs, bs = [], []
    for k in range(6):
        xk = A.createVecRight()
        arr = np.zeros((r1 - r0, 6))
        arr[local_b - r0, :3] = (x[local_b] - center) @ eps[k].T
        xk.setArray(arr.ravel())
        bk = A.createVecLeft()
        A.mult(xk, bk)
        bk.scale(-1.0)
        xs.append(xk)
        bs.append(bk)
    diag = A.getDiagonal()
    dscale = diag.sum() / diag.getSize()  # identity rows scaled like the matrix
    A.zeroRowsColumns(bdofs, diag=dscale)
    for xk, bk in zip(xs, bs):
        barr = bk.getArray()
        barr.reshape(-1, 6)[local_b - r0, :3] = dscale * xk.getArray().reshape(-1, 6)[local_b - r0, :3]
    A.setNearNullSpace(near_nullspace(PETSc, A, x[r0:r1], x.mean(axis=0)))
    # CG and the fine-level smoother are bound by MatMult's memory traffic; a
    # symmetric-block copy (upper 6x6 blocks, one index per block) moves about
    # a third of AIJ's bytes and halves the solve time. GAMG keeps building its
    # hierarchy from the AIJ matrix (it cannot use (S)BAIJ in PETSc 3.18).
    t0 = time.perf_counter()
    if PETSc.Options().getString("amfe_operator_type", "sbaij") == "aij":
        A_op = A
    else:
        A_op = sbaij_operator(PETSc, comm, frame.n_particles, r0, r1, *block_rows,
                              fixed=boundary, diag=dscale)
    del block_rows
    t_assembly += time.perf_counter() - t0

    with petsc_options(PETSc, ksp_options):
        ksp = make_ksp(PETSc, A_op, A, rtol=rtol, max_it=max_it)
        t0 = time.perf_counter()
        ksp.setUp()
        t_setup = time.perf_counter() - t0

    iterations, residuals, moments, solutions = [], [], [], []
    case_seconds = []
    r = A.createVecLeft()
    f = A_b.createVecLeft()
    scatter, u0 = PETSc.Scatter.toZero(xs[0])
    for k in range(6):
        uk = A.createVecRight()
        t0 = time.perf_counter()
        ksp.solve(bs[k], uk)
        case_seconds.append(time.perf_counter() - t0)
        check_converged(PETSc, ksp, f"load case {CASE_NAMES[k]} (KUBC)")
        iterations.append(int(ksp.getIterationNumber()))
        A.mult(uk, r)
        r.aypx(-1.0, bs[k])
        residuals.append(float(r.norm() / bs[k].norm()))
        A_b.mult(uk, f)
        # Bagi stress times V, summed over ranks: sum_b f_b (x) (x_b - x_c).
        local = bagi_stress(f.getArray().reshape(-1, 3), x[local_b], center, 1.0)
        moments.append(comm.tompi4py().allreduce(local))
        scatter.scatter(uk, u0, addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        if rank == 0:
            solutions.append(u0.getArray().reshape(-1, 6).copy())
    pc = ksp.getPC()
    out = dict(
        u=np.array(solutions) if rank == 0 else None,
        moments=np.array(moments), center=center, boundary=boundary,
        iterations=iterations, residuals=residuals, setup_seconds=t_setup,
        solve_seconds=sum(case_seconds), case_seconds=case_seconds, assembly_seconds=t_assembly,
        ksp_type=ksp.getType(), pc_type=pc.getType(), rtol=ksp.getTolerances()[0])
    for obj in (ksp, A_op, A, A_b, isrow, iscol, scatter, u0, r, f, *xs, *bs):
        obj.destroy()
    return out

"""The Bagi strain's adjoint solves: KUBC's strain to second order on beds with free hull vertices.

The strain's six Voigt components are linear functionals g_m . x of a case's
solution over its free hull vertices' translations
(:func:`amfe.solvers.correction.strain_loads`). Their adjoint solutions z_m
(A z_m = g_m, the group's constrained operator) are not at hand after the six
cases, unlike the stress's: they take six more solves with the same
preconditioner set-up (one block CG where the cases took one). Then
G_mj = z_m . r_j corrects case j's strain: e_m(x*_j) = e_m(x_j) + G_mj up to
e_z^T A e_j (docs/model.md section 5, "Strain to second order").
"""
import time

import numpy as np

from amfe.errors import AmfeError
from amfe.model.averages import hull_of
from amfe.solvers.blocksolve import block_path_applies, solve_block
from amfe.solvers.correction import free_hull_vertices, strain_loads, strain_weights


def strain_cross(op, us):
    """(G (m, k) with G_mj = z_m . r_j, adjoint iterations (m,), seconds) for an operator ``op``
    (:class:`amfe.solvers.operator.ConstrainedOperator` whose group carries ``adjoint`` loads
    (m, n, 6)) and its cases' solutions ``us`` (k PETSc Vecs, prescribed DOFs exact).

    The adjoint solves run at the operator's rtol; one that does not converge is an
    AmfeError (its correction would not be second order)."""
    A, ksp, r0, r1 = op.A, op.ksp, op.r0, op.r1
    t0 = time.perf_counter()
    gs = []
    for load in op.group.adjoint:
        g = A.createVecLeft()
        g.setArray(load[r0:r1].ravel())
        gs.append(g)
    zs, its, reasons = None, [], []
    if block_path_applies(ksp, len(gs), op.block_option, op.diagnose):
        cols = solve_block(ksp, gs, None)
        if cols is not None:
            zs = [c.u for c in cols]
            its = [c.iterations for c in cols]
            reasons = [c.ksp.getConvergedReason() for c in cols]
    if zs is None:  # one at a time (the operator's own path)
        ksp.setInitialGuessNonzero(False)
        zs = []
        for g in gs:
            z = A.createVecRight()
            ksp.solve(g, z)
            zs.append(z)
            its.append(int(ksp.getIterationNumber()))
            reasons.append(ksp.getConvergedReason())
    bad = [m for m, why in enumerate(reasons) if why <= 0]
    r = A.createVecLeft()
    try:
        if bad:
            raise AmfeError(f"the strain's adjoint solve(s) {bad} did not converge (reasons "
                            f"{[int(reasons[m]) for m in bad]}, iterations {its}); give "
                            "-amfe_strain_adjoint no or another --rtol")
        G = np.empty((len(zs), len(us)))
        for j, u in enumerate(us):
            A.mult(u, r)
            r.aypx(-1.0, op._b[j])
            G[:, j] = [z.dot(r) for z in zs]
    finally:
        for v in gs + zs + [r]:
            v.destroy()
    return G, [int(i) for i in its], time.perf_counter() - t0


def attach_strain_adjoint(frame, groups, mpi):
    """Give KUBC's group the strain's adjoint loads where its hull has free vertices; whether it
    did (the same on every rank: rank 0 takes the hull, qhull, and sends its weights)."""
    w = None
    if mpi.rank == 0:
        hull = hull_of(frame.centers)
        free = free_hull_vertices(frame, groups, hull)
        if free is not None and free.size:
            w = strain_weights(hull)
    w = mpi.bcast(w)
    if w is None:
        return False
    groups[0].adjoint = strain_loads(*w, groups[0].fixed)
    return True

"""Load cases on a distributed frame: prescribed DOFs, one operator per group of cases.

A group is a set of load cases that prescribe the same DOFs (with different
values): they share one constrained operator and one preconditioner set-up.
KUBC is one group of six cases; the mixed boundary conditions are six groups
of one. Prescribed DOFs are imposed with MatZeroRowsColumns (identity rows and
columns scaled like the matrix, the values lifted into the right-hand sides),
which keeps the AIJ block size 6 and the near null space for GAMG. Reactions
come from the unconstrained rows of the constrained particles' translations.

CG multiplies with a symmetric-block (SBAIJ) copy of the constrained matrix:
CG and the fine-level smoother are bound by MatMult's memory traffic, and the
upper 6x6 blocks with one index per block move about a third of AIJ's bytes.
GAMG is built from the AIJ matrix (it cannot use (S)BAIJ in PETSc 3.18). The
PETSc option -amfe_operator_type aij turns the copy off.
"""
import time
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.homogenize import bagi_stress
from .assembly import aij_from_blocks, sbaij_operator
from .ksp import IndefinitePreconditioner, check_converged, make_ksp, petsc_options

# GAMG's Chebyshev smoothers scale by an estimate of the largest eigenvalue of
# D^-1 A from 10 Krylov steps. Very stiff bonds among the prescribed particles
# (a* within ~1e-7 of the critical value) can make it too low: the smoother
# amplifies the top modes and CG stops with DIVERGED_INDEFINITE_PC. The retry
# estimates with 50 steps (measured: converges, 1e-10 from a direct solve).
ROBUST_ESTEIG = {"pc_gamg_esteig_ksp_max_it": 50}
from .nullspace import near_nullspace


@dataclass
class Group:
    """Load cases sharing their prescribed DOFs.

    fixed (n,6) bool: prescribed DOFs; values: list of (n,6) arrays, one per
    case (entries outside ``fixed`` are ignored); names: case names;
    null_modes: (m, n, 6) rigid modes the constraints leave free (the
    operator is then singular and CG works in their orthogonal complement;
    the right-hand sides are consistent because K annihilates them);
    guesses: optional list of (n,6) initial guesses, one per case.
    """

    fixed: np.ndarray
    values: list
    names: list
    null_modes: np.ndarray = field(default=None)
    guesses: list = field(default=None)


def solve_group(PETSc, frame, comm, r0, r1, block_rows, group, center, *, rtol, max_it=None,
                ksp_options=None, diagnose=False, gather=True, log=None):
    """Solve one group's cases. Returns a list of per-case dicts and a set-up record.

    Per case: u (n,6) on rank 0 (None elsewhere) if ``gather``; moment (3,3) =
    sum over constrained particles of f (x) (x - center), summed over ranks;
    iterations; residual (true, relative); seconds; and with ``diagnose`` the
    extreme eigenvalue estimates of the preconditioned operator.
    """
    n, nloc = frame.n_particles, r1 - r0
    x = frame.centers
    t0 = time.perf_counter()
    A = aij_from_blocks(PETSc, comm, n, r0, r1, *block_rows)
    fixed_loc = group.fixed[r0:r1]
    dofs = (np.flatnonzero(fixed_loc.ravel()) + 6 * r0).astype(PETSc.IntType)
    held = np.flatnonzero(fixed_loc.any(axis=1)) + r0  # particles with a reaction
    rdofs = (6 * held[:, None] + np.arange(3)).ravel().astype(PETSc.IntType)
    isrow = PETSc.IS().createGeneral(rdofs, comm=comm)
    iscol = PETSc.IS().createStride(6 * nloc, first=6 * r0, step=1, comm=comm)
    A_r = A.createSubMatrix(isrow, iscol)  # unconstrained rows: the reactions

    xs, bs = [], []
    for values in group.values:
        xk = A.createVecRight()
        xk.setArray(np.where(fixed_loc, values[r0:r1], 0.0).ravel())
        bk = A.createVecLeft()
        A.mult(xk, bk)
        bk.scale(-1.0)
        xs.append(xk)
        bs.append(bk)
    # A prescribed DOF keeps its own diagonal entry on its identity row: one
    # scale for all of them (say the mean diagonal) lets a few very stiff bonds
    # dominate ||b||, and rtol * ||b|| then no longer controls the free rows.
    diag = A.getDiagonal()
    A.zeroRowsColumns(dofs, diag=1.0)
    local_dofs = dofs - 6 * r0
    d = A.getDiagonal()
    d.getArray()[local_dofs] = diag.getArray()[local_dofs]
    A.setDiagonal(d)
    d.destroy()
    dvals = diag.getArray()[local_dofs]
    for xk, bk in zip(xs, bs):
        bk.getArray()[local_dofs] = dvals * xk.getArray()[local_dofs]
    A.setNearNullSpace(near_nullspace(PETSc, A, x[r0:r1], x.mean(axis=0)))
    if PETSc.Options().getString("amfe_operator_type", "sbaij") == "aij":
        A_op = A
    else:
        A_op = sbaij_operator(PETSc, comm, n, r0, r1, *block_rows, fixed=group.fixed)
    nullsp = None
    if group.null_modes is not None:
        nullsp = _nullspace(PETSc, A, group.null_modes[:, r0:r1])
        A.setNullSpace(nullsp)
        A_op.setNullSpace(nullsp)
    t_assembly = time.perf_counter() - t0

    with petsc_options(PETSc, ksp_options):
        ksp = make_ksp(PETSc, A_op, A, rtol=rtol, max_it=max_it)
        if diagnose:
            ksp.setComputeEigenvalues(True)
        t0 = time.perf_counter()
        ksp.setUp()
        t_setup = time.perf_counter() - t0
    if log:
        log(f"operator for {', '.join(group.names)}: assembled in {t_assembly:.2f} s, "
            f"{ksp.getPC().getType()} set up in {t_setup:.2f} s")
    record = {"setup_seconds": t_setup, "assembly_seconds": t_assembly,
              "ksp_type": ksp.getType(), "pc_type": ksp.getPC().getType(),
              "rtol": ksp.getTolerances()[0]}
    if diagnose:
        record.update(_pc_complexity(PETSc, ksp))

    r = A.createVecLeft()
    f = A_r.createVecLeft()
    scatter, u0 = PETSc.Scatter.toZero(xs[0])
    cases = []
    # (a direct solve, KSP preonly, takes no initial guess)
    use_guess = group.guesses is not None and ksp.getType() != "preonly"
    guesses = group.guesses if use_guess else [None] * len(bs)
    ksp.setInitialGuessNonzero(use_guess)
    for name, bk, guess in zip(group.names, bs, guesses):
        uk = A.createVecRight()
        if guess is not None:
            uk.setArray(guess[r0:r1].ravel())
        t0 = time.perf_counter()
        ksp.solve(bk, uk)
        seconds = time.perf_counter() - t0
        check_converged(PETSc, ksp, f"load case {name}")
        if log:
            log(f"load case {name}: {ksp.getIterationNumber()} iterations, {seconds:.2f} s")
        A.mult(uk, r)
        r.aypx(-1.0, bk)
        bnorm = bk.norm()  # zero when a case prescribes nothing but zeros
        case = {"name": name, "iterations": int(ksp.getIterationNumber()),
                "residual": float(r.norm() / bnorm if bnorm > 0 else r.norm()), "seconds": seconds}
        if diagnose:
            smax, smin = ksp.computeExtremeSingularValues()
            case.update(eig_max=float(smax), eig_min=float(smin),
                        condition=float(smax / smin) if smin > 0 else float("inf"))
        A_r.mult(uk, f)
        local = bagi_stress(f.getArray().reshape(-1, 3), x[held], center, 1.0)
        case["moment"] = comm.tompi4py().allreduce(local)
        if gather:
            scatter.scatter(uk, u0, addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            case["u"] = u0.getArray().reshape(-1, 6).copy() if comm.getRank() == 0 else None
        uk.destroy()
        cases.append(case)
    for obj in (ksp, A_op, A, A_r, isrow, iscol, scatter, u0, r, f, diag, *xs, *bs):
        obj.destroy()
    if nullsp is not None:
        nullsp.destroy()
    return cases, record


def _nullspace(PETSc, A, local_modes):
    vecs = []
    for m in local_modes:
        v = A.createVecRight()
        v.setArray(m.ravel())
        for w in vecs:
            v.axpy(-v.dot(w), w)
        v.normalize()
        vecs.append(v)
    return PETSc.NullSpace().create(vectors=vecs, comm=A.getComm())


def _pc_complexity(PETSc, ksp):
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


def solve_load_cases(PETSc, frame, comm, groups, *, rtol, max_it=None, ksp_options=None,
                     diagnose=False, center=None, log=None):
    """Solve every group of load cases on ``frame``; merge the per-case results.

    Returns a dict (the same on every rank except u): u (cases, n, 6) on rank 0,
    None elsewhere; moments (cases, 3, 3); names, iterations, residuals,
    case_seconds (lists per case); assembly_seconds (element blocks and every
    group's matrices), setup_seconds (all preconditioner set-ups),
    solve_seconds; ksp_type, pc_type, rtol; and with ``diagnose`` a list of
    per-case diagnostics (iterations, true residual, eigenvalue estimates,
    GAMG complexities). ``log``: called with a progress line per operator and
    per case (on every rank; the caller decides who prints).
    """
    from amfe.homogenize import box_center
    from .assembly import local_block_rows
    from .partition import row_ranges

    size, rank = comm.getSize(), comm.getRank()
    ranges = row_ranges(frame.n_particles, size)
    r0, r1 = int(ranges[rank]), int(ranges[rank + 1])
    center = box_center(frame.centers) if center is None else center
    t0 = time.perf_counter()
    block_rows = local_block_rows(frame, r0, r1)
    t_blocks = time.perf_counter() - t0
    cases, records, group_records, notes = [], [], [], []
    for group in groups:
        kwargs = dict(rtol=rtol, max_it=max_it, diagnose=diagnose, log=log)
        try:
            c, rec = solve_group(PETSc, frame, comm, r0, r1, block_rows, group, center,
                                 ksp_options=ksp_options, **kwargs)
        except PETSc.Error as exc:
            # e.g. an option PETSc cannot use (-pc_type unknown); PETSc printed the details
            raise AmfeError(f"PETSc stopped with {exc} while solving cases "
                            f"{', '.join(group.names)}; its message is above. Check the PETSc "
                            "options given.") from None
        except IndefinitePreconditioner as exc:
            if "pc_gamg_esteig_ksp_max_it" in (ksp_options or {}):
                raise
            notes.append(f"cases {', '.join(group.names)}: {str(exc).split(':')[0]} met an "
                         "indefinite preconditioner; set up again with "
                         "-pc_gamg_esteig_ksp_max_it 50")
            c, rec = solve_group(PETSc, frame, comm, r0, r1, block_rows, group, center,
                                 ksp_options={**(ksp_options or {}), **ROBUST_ESTEIG}, **kwargs)
        cases += c
        records += [rec] * len(c)
        group_records.append(rec)
    out = {
        "u": np.array([c["u"] for c in cases]) if rank == 0 else None,
        "moments": np.array([c["moment"] for c in cases]),
        "center": center,
        "names": [c["name"] for c in cases],
        "iterations": [c["iterations"] for c in cases],
        "residuals": [c["residual"] for c in cases],
        "case_seconds": [c["seconds"] for c in cases],
        "solve_seconds": float(sum(c["seconds"] for c in cases)),
        "setup_seconds": float(sum(rec["setup_seconds"] for rec in group_records)),
        "assembly_seconds": t_blocks + float(sum(rec["assembly_seconds"] for rec in group_records)),
        "ksp_type": records[0]["ksp_type"], "pc_type": records[0]["pc_type"],
        "rtol": float(records[0]["rtol"]),
        "notes": notes,
    }
    if diagnose:
        keep = ("iterations", "residual", "eig_min", "eig_max", "condition")
        pc_keys = ("levels", "grid_complexity", "operator_complexity")
        out["diagnostics"] = [
            {"case": c["name"], **{k: c[k] for k in keep if k in c},
             **{k: rec[k] for k in pc_keys if k in rec}}
            for c, rec in zip(cases, records)]
    return out

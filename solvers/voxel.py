"""homogenize_voxel: the continuum of a bed's spheres by voxel finite elements, on PETSc.

docs/model.md, section 10. The geometry and mesh are pure numpy
(:mod:`amfe.model.voxel`, :mod:`amfe.model.voxelmesh`, :mod:`amfe.model.hex8`),
built alike on every rank; each rank owns a contiguous block of active nodes
(a slab in z) and assembles its rows into an AIJ matrix of block size 3. The
six unit macro-strains are solved with CG + GAMG (near null space: the six
rigid-body modes of the node coordinates), one operator and set-up for the
six cases. KUBC prescribes u = eps (x - x_c) on every active node inside
the frame's boundary particles (the box's faces for a solid built without
them); the periodic condition solves for the periodic part on the torus.
C comes from the work of the loads, corrected to second order in the solver's
error (the dual-weighted residual of :mod:`amfe.solvers.correction`).

Units inside: lengths in the first voxel side h_x, stresses in E.
"""
import logging
import time
from collections import namedtuple
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from amfe.errors import AmfeError
from amfe.io.result import Result
from amfe.io.result_meta import header
from amfe.model.averages import asymmetry, compliance_and_constants, dual_corrected, unit_strains
from amfe.model.hex8 import VERTICES, element_stiffness
from amfe.model.material import STEEL
from amfe.model.memory import check_memory
from amfe.model.options import SolveOptions
from amfe.model.volumebox import unit_warnings, volume_box_record
from amfe.model.voxel import voxel_bytes, voxel_solid
from amfe.model.voxelmesh import block_rows, build_mesh, element_loads
from amfe.solvers.consistency import agree_across_ranks
from amfe.solvers.driver import petsc_comm
from amfe.solvers.inputs import checked_inputs, given_size
from amfe.solvers.ksp import RESIDUAL_FACTOR, check_solution, make_ksp, petsc_options
from amfe.solvers.options import call_options
from amfe.solvers.partition import row_ranges
from amfe.solvers.petsc import unused_options_warning
from amfe.solvers.petsclib import PETSc
from amfe.solvers.voxelfree import ElementProduct, matrix_free_ksp, shell, two_grid

LOG = logging.getLogger("amfe.solvers")
EPS = float(np.finfo(float).eps)
VOXEL_RTOL = 1e-5
"""Default CG tolerance. With the second-order correction the constants at 1e-5 are
within 7.6e-10 (KUBC) and 5.7e-12 (periodic) of those at 1e-12 on a 48-particle
periodic bed at 3 um voxels, in 8 and 11 iterations against 21 and 26
(docs/model.md, section 10)."""
#: The conditions the voxel model solves; ``periodic``: it needs the bed's periodic box.
Condition = namedtuple("Condition", "periodic")
VOXEL_CONDITIONS = {"kubc": Condition(False), "periodic": Condition(True)}
#: How the stiffness is applied: an assembled AIJ matrix, or the elements on the fly.
VOXEL_OPERATORS = ("assembled", "matrix-free")


def check_operator(operator):
    """AmfeError unless ``operator`` is one of :data:`VOXEL_OPERATORS`."""
    if operator not in VOXEL_OPERATORS:
        raise AmfeError(f"the voxel operator is one of {', '.join(VOXEL_OPERATORS)}, "
                        f"not {operator!r}")


def homogenize_voxel(bed, options=None, comm=None, *, voxel_size=None, input_error=None,
                     initial="affine", operator="assembled"):
    """Effective C of the union of a bed's spheres, meshed by voxels of side ``voxel_size``.

    bed: a checked :class:`~amfe.model.bed.Bed` (centres (N, 3) [m], radii (N,)
    [m]; ``attrs["periodic"]`` (3,) [m], the period box, for bc "periodic";
    ``attrs["size"]`` (3,) [m], the recorded box, V under KUBC). options: a
    :class:`~amfe.model.options.SolveOptions` (default: its defaults): bc
    "kubc" (on the frame's box, docs/model.md section 5) or "periodic"; rtol
    (default :data:`VOXEL_RTOL`, 1e-5), max_it, ksp_options,
    accept_unconverged, max_memory (bytes; a model estimated to need more is
    refused before its grid is allocated), material (None: the bed's, else
    steel; E and nu used) and material_source. voxel_size [m] (default mean
    radius / 4). initial: "affine" (the applied field, KUBC) or "zero" (the
    initial guess). operator: "assembled" or "matrix-free" (:func:`voxel_stiffness`).
    comm, input_error: as :func:`amfe.solvers.driver.homogenize_bed`:
    the ranks' inputs are compared first (one collective), so a bad or
    differing input is the same error on every rank, never a hang.
    Returns the :class:`~amfe.io.result.Result` of homogenize_bed's shape
    (properties, C, S [Pa, 1/Pa], volume [m^3], counts, solver, material,
    removed, warnings, the header) whose extra holds a ``model`` record (name
    "voxel", voxel size, voxels, solid fraction, DOFs, neck share, pieces
    removed). Progress and warnings leave through the logger "amfe.solvers"
    on rank 0. Raises AmfeError on every rank for bad input or a failed solve.
    """
    if options is None and input_error is None:
        options = SolveOptions()
    # this call's PETSc options, in the database for this call alone (amfe.solvers.options)
    with call_options(options.petsc_args if isinstance(options, SolveOptions) else ()) as scope:
        return _homogenize_voxel(bed, options, comm, input_error, scope,
                                 (voxel_size, initial, operator))


def _homogenize_voxel(bed, options, comm, input_error, scope, how):
    """:func:`homogenize_voxel` inside its :func:`~amfe.solvers.options.call_options`;
    how: (voxel_size, initial, operator)."""
    voxel_size, initial, operator = how
    comm = petsc_comm(comm)
    mpi = comm.tompi4py()
    error = input_error
    try:
        if error is None and isinstance(options, SolveOptions) \
                and options.bc not in VOXEL_CONDITIONS:
            raise AmfeError(f"the voxel model solves bc 'kubc' or 'periodic', not {options.bc!r}")
        if initial not in ("affine", "zero"):
            raise AmfeError(f"initial must be 'affine' or 'zero', got {initial!r}")
        check_operator(operator)
    except AmfeError as exc:
        error = error or exc
    agree_across_ranks(mpi, {"voxel": repr((voxel_size, initial, operator))}, None)
    inp = checked_inputs(mpi, bed, options, VOXEL_CONDITIONS, error)
    options = replace(inp.options, material=inp.material)
    t0 = time.perf_counter()
    geo = voxel_solid(bed.centers, bed.radii, voxel_size, inp.box if options.bc == "periodic"
                      else None, size=given_size(bed, options), max_memory=options.max_memory,
                      ranks=mpi.size, even=operator == "matrix-free")
    geo.warnings.extend(unit_warnings(bed.radii, geo.grid.n * geo.grid.h))
    for line in geo.warnings if mpi.rank == 0 else ():
        LOG.warning(line)
    t_geo = time.perf_counter() - t0
    C, sol, mesh = voxel_stiffness(geo, options, comm, initial=initial, operator=operator)
    sol["warnings"] += [w for w in (unused_options_warning(mpi.rank, names=scope.unused()),
                                    scope.ignored_warning(mpi.rank)) if w]
    return Result.from_dict(_result(bed, geo, (C, sol, mesh), inp.record, mpi.size, t_geo))


def _result(bed, geo, solved, record, ranks, t_geo):
    """The result dict of a solved voxel model (docs/model.md, sections 6 and 10)."""
    C, sol, mesh = solved
    S, props = compliance_and_constants(C)
    model = {"name": "voxel", "voxel_size": float(geo.grid.h.max()),
             "voxel_sides": geo.grid.h.tolist(), "voxels": geo.grid.n.tolist(),
             "solid_voxels": int(mesh.n_elements), "solid_fraction": geo.solid_fraction,
             "dofs": 3 * mesh.n_nodes, "nodes": int(mesh.n_nodes),
             "necks_resolved_share": geo.neck_share, "pieces_removed": geo.pieces_removed,
             "voxels_removed": geo.voxels_removed, "element": "hex8 (trilinear, 2x2x2 Gauss)",
             "box": {"min": geo.grid.lo.tolist(),
                     "max": (geo.grid.lo + geo.grid.n * geo.grid.h).tolist()},
             "geometry_seconds": t_geo}
    if geo.grip is not None:    # KUBC's grip: the frame's boundary particles (section 10)
        model["grip"] = {"rule": "nodes inside the frame's boundary particles",
                         "particles": int(len(geo.grip_particles)),
                         "nodes": int(mesh.boundary_nodes(geo.grip).size)}
    out = header("homogenize", bed.centers, bed.radii, record)
    out["counts"].update(particles_kept=int(len(geo.kept)), bonds_kept=geo.n_bonds,
                         bonds_input=geo.n_bonds_input)
    n = int(len(bed.radii))
    out.update({
        "properties": {k: float(v) for k, v in props.items()},
        "C": C.tolist(), "S": S.tolist(), "volume": geo.grid.volume,
        "volume_box": volume_box_record(geo.grid.lo, geo.grid.n * geo.grid.h, geo.box_source),
        "n_particles": n, "n_removed": n - int(len(geo.kept)), "removed": geo.removed,
        "n_bonds": geo.n_bonds, "bc": "periodic" if mesh.periodic else "kubc", "ranks": ranks,
        "solver": {**_method(sol["operator"]), "ksp_type": sol["ksp_type"],
                   "pc_type": sol["pc_type"],
                   "rtol": sol["rtol"], "residual_limit": RESIDUAL_FACTOR * sol["rtol"],
                   "iterations": sol["iterations"], "residuals": sol["residuals"],
                   "setup_seconds": sol["setup_seconds"], "solve_seconds": sol["solve_seconds"],
                   "assembly_seconds": sol["assembly_seconds"], "C_asymmetry": float(asymmetry(C)),
                   "stress_asymmetry": sol["stress_asymmetry"], **sol["stats"]},
        "material": record, "warnings": geo.warnings + sol["warnings"], "model": model})
    return out


def _method(operator):
    """The solver record's method and reason for a voxel operator."""
    if operator == "assembled":
        return {"method": "gamg", "reason": "voxel model: CG + GAMG, rigid-body near null space",
                "operator": operator}
    return {"method": "matrix-free", "operator": operator,
            "reason": "voxel model: CG on the elements' shell operator, two-grid PCMG "
                      "(Chebyshev + Jacobi; the grid twice as coarse by GAMG)"}


def voxel_stiffness(geo, options, comm, *, initial="affine", operator="assembled"):
    """(C (6, 6) [Pa], solve record, mesh) of a :class:`~amfe.model.voxel.VoxelSolid`.

    geo.solid are the voxels meshed (load-carrying already); options: a
    :class:`~amfe.model.options.SolveOptions` (bc "periodic": the grid is a
    period box; material None: steel). initial as :func:`homogenize_voxel`.
    operator: "assembled" (AIJ + GAMG) or "matrix-free" (a shell of the
    elements, preconditioned on the grid twice as coarse, :mod:`amfe.solvers.voxelfree`).
    """
    check_operator(operator)
    mpi = comm.tompi4py()
    periodic = options.bc == "periodic"
    options = replace(options, rtol=VOXEL_RTOL if options.rtol is None else options.rtol)
    material = options.material or STEEL
    mesh = build_mesh(geo.solid, periodic=periodic)
    voxels = int(np.prod(geo.grid.n))
    check_memory(voxel_bytes(voxels, mesh.n_nodes, mpi.size, operator), options.max_memory,
                 f"a voxel model of {mesh.n_nodes:.3g} nodes ({3 * mesh.n_nodes:.3g} DOFs) on "
                 f"{mpi.size} rank(s)")
    _log(mpi, f"voxels: {geo.grid.n.tolist()} of {geo.grid.h.max():.3g} m, {mesh.n_elements} "
         f"solid (fraction {geo.solid_fraction:.4f}), {mesh.n_nodes} nodes, {len(geo.kept)} "
         f"particles; {100 * geo.neck_share:.0f} % of necks >= 2 voxels")
    h = geo.grid.h / geo.grid.h[0]
    Ke = element_stiffness(h, 1.0, material.nu)
    bounds = row_ranges(mesh.n_nodes, mpi.size)
    r0, r1 = int(bounds[mpi.rank]), int(bounds[mpi.rank + 1])
    x_local = mesh.node_ijk(np.arange(r0, r1)) * h          # node coordinates, units h_x
    volume = float(np.prod(geo.grid.n * h))
    cases = _periodic(mesh, Ke, h, r0, r1) if periodic else \
        _kubc(mesh.boundary_nodes(geo.grip), x_local, geo.grid.n * h / 2.0, r0, r1)
    t1 = time.perf_counter()
    if operator == "assembled":
        ops = _assembled(_assemble(comm, mesh, Ke, r0, r1), cases, x_local, options)
    else:
        ops = _matrix_free(comm, mesh, Ke, h, (r0, r1), geo.grip, cases, options)
    t_asm = time.perf_counter() - t1 - ops.setup
    sol = _solve(ops, cases, x_local, options, initial)
    sol["operator"] = operator
    W = cases["W0"] - sol["work"] if periodic else sol["work"]
    W, sol["stats"] = dual_corrected(W, [sol["cross"]], -1)
    sol["assembly_seconds"] = t_asm   # sol["rtol"]: the KSP's, options included (issue 45)
    return W / volume * material.E, sol, mesh


def _log(mpi, line):
    """One progress line to the logger, on rank 0 only (the face decides what prints)."""
    if mpi.rank == 0:
        LOG.info(line)


def _assemble(comm, mesh, Ke, r0, r1):
    """Rows [3 r0, 3 r1) of the stiffness as a distributed AIJ matrix of block size 3."""
    indptr, cols, blocks = block_rows(mesh, Ke, r0, r1)
    nloc, n = r1 - r0, mesh.n_nodes
    csr = sp.bsr_matrix((blocks, cols, indptr), shape=(3 * nloc, 3 * n)).tocsr()
    it = PETSc.IntType
    A = PETSc.Mat().createAIJ(size=((3 * nloc, 3 * n), (3 * nloc, 3 * n)), bsize=3,
                              csr=(csr.indptr.astype(it), csr.indices.astype(it), csr.data),
                              comm=comm)
    A.setOption(PETSc.Mat.Option.NO_OFF_PROC_ENTRIES, True)
    A.assemble()
    return A


def _kubc(boundary, x_local, center, r0, r1):
    """KUBC's six cases: prescribed local DOFs and their values (6, 3 nloc) and the affine
    fields (6, 3 nloc) [units h_x], eps_k (x - x_c) on every local node; boundary: the
    prescribed active nodes (global numbers, sorted)."""
    mine = boundary[(boundary >= r0) & (boundary < r1)] - r0
    dofs = (3 * mine[:, None] + np.arange(3)).ravel()
    affine = np.array([((x_local - center) @ e.T).ravel() for e in unit_strains()])
    fixed = np.zeros((6, affine.shape[1]))
    fixed[:, dofs] = affine[:, dofs]
    return {"dofs": dofs, "values": fixed, "affine": affine, "forces": None}


def _periodic(mesh, Ke, h, r0, r1):
    """The periodic condition's six cases on the torus (docs/model.md, section 10):
    loads F_k = -sum_e Ke q_k, q_k = eps_k applied to the element's vertex offsets, node 0's
    translations pinned (the solution is unique up to a translation), and
    W0_IJ = n_e q_I . Ke q_J."""
    local_vertices = VERTICES * h
    q = np.array([(local_vertices @ e.T).ravel() for e in unit_strains()])   # (6, 24)
    forces = np.array([-element_loads(mesh, Ke, qk, r0, r1).ravel() for qk in q])
    # the loads before they cancel between elements (a solid node gets none): the scale of
    # their rounding error, for the residual's floor
    gross = np.array([np.sum(element_loads(mesh, np.abs(Ke), np.abs(qk), r0, r1) ** 2)
                      for qk in q])
    dofs = np.arange(3) if r0 == 0 and r1 > 0 else np.zeros(0, np.int64)
    W0 = mesh.n_elements * q @ Ke @ q.T
    n = 3 * (r1 - r0)
    return {"dofs": dofs, "values": np.zeros((6, n)), "affine": np.zeros((6, n)),
            "forces": forces, "W0": W0, "gross_sq": gross}


Operators = namedtuple("Operators", "A0 A ksp setup unused norm_A")
"""A0: the stiffness; A: with the prescribed DOFs as identity rows and columns; ksp
(set up) on A; setup [s]; unused: PETSc options never read; norm_A: ||A0||_F or a
bound of it (the residual floor's scale)."""


def _assembled(A0, cases, x_local, options):
    """:class:`Operators` of the assembled AIJ matrix A0: CG + GAMG, rigid-body near null
    space of the node coordinates."""
    r0 = A0.getOwnershipRange()[0]
    dofs = cases["dofs"].astype(PETSc.IntType) + r0
    A = A0.duplicate(copy=True)
    A.zeroRowsColumns(dofs, diag=1.0)
    coords = A.createVecRight()
    coords.setBlockSize(3)
    coords.setArray(x_local.ravel())
    A.setNearNullSpace(PETSc.NullSpace().createRigidBody(coords))
    t0 = time.perf_counter()
    with petsc_options(options.ksp_options) as unused:
        ksp = make_ksp(A, rtol=options.rtol, max_it=options.max_it)
        ksp.setInitialGuessNonzero(ksp.getType() != "preonly")   # preonly: no guess
        ksp.setUp()
    return Operators(A0, A, ksp, time.perf_counter() - t0, unused,
                     A0.norm(PETSc.NormType.FROBENIUS))


def _matrix_free(comm, mesh, Ke, h, rows, grip, cases, options):
    """:class:`Operators` of the element shell (:mod:`amfe.solvers.voxelfree`): CG + the
    two-grid PCMG; grip: KUBC's gripped grid nodes (None: the box's faces)."""
    r0, r1 = rows
    fixed = np.array([0]) if mesh.periodic else mesh.boundary_nodes(grip)
    free = ElementProduct(comm, mesh, Ke, r0, r1)
    A0 = shell(comm, free)
    A = shell(comm, free.with_fixed(cases["dofs"]))
    t0 = time.perf_counter()
    Ac, P, _ = two_grid(comm, mesh, Ke, h, r0, r1, fixed, grip)
    with petsc_options(options.ksp_options) as unused:
        ksp = matrix_free_ksp(A, Ac, P, options.rtol, options.max_it)
        ksp.setInitialGuessNonzero(ksp.getType() != "preonly")   # preonly: no guess
        ksp.setUp()
    return Operators(A0, A, ksp, time.perf_counter() - t0, unused, free.frobenius_bound())


def _solve(ops, cases, x_local, options, initial):
    """Solve the six cases on one operator; the work matrix and cross products.

    work[i, j]: KUBC g_i . A0 x_j (the prescribed translations' work against the
    reactions), periodic F_i . x_j; cross[i, j] = x_i . r_j, r_j the true residual
    on the free DOFs (the prescribed values set exactly first).
    """
    A0, A, ksp, setup, unused = ops.A0, ops.A, ops.ksp, ops.setup, ops.unused
    mpi = A0.getComm().tompi4py()
    dofs = cases["dofs"].astype(PETSc.IntType) + A.getOwnershipRange()[0]
    _log(mpi, f"preconditioner set-up {setup:.2f} s")
    norm_A = ops.norm_A
    xs, rs, loads, iterations, residuals, warnings = [], [], [], [], [], []
    t1 = time.perf_counter()
    for k in range(6):
        g, x, b = A.createVecRight(), A.createVecRight(), A.createVecRight()
        g.setArray(cases["values"][k])
        A0.mult(g, b)
        b.scale(-1.0)
        if cases["forces"] is not None:
            b.setArray(b.getArray() + cases["forces"][k])
        b.setValues(dofs, cases["values"][k][cases["dofs"]])
        b.assemble()
        x.setArray(cases["affine"][k] if initial == "affine" else 0.0)
        ksp.solve(b, x)
        x.setValues(dofs, cases["values"][k][cases["dofs"]])   # exact prescribed values
        x.assemble()
        r = b.duplicate()
        A.mult(x, r)
        r.aypx(-1.0, b)                                         # r = b - A x (free rows)
        bnorm = b.norm()
        residual = r.norm() / bnorm if bnorm > 0 else 0.0
        gross = (np.sqrt(mpi.allreduce(cases["gross_sq"][k])) if "gross_sq" in cases
                 else norm_A * g.norm())
        floor = EPS * (norm_A * x.norm() + gross) / bnorm if bnorm > 0 else 0.0
        warning, _ = check_solution(ksp, f"voxel load case {k}", residual,
                                    lambda: (residual, "unpreconditioned", floor),
                                    accept=options.accept_unconverged)
        if warning:
            warnings.append(warning)
        iterations.append(int(ksp.getIterationNumber()))
        residuals.append(float(residual))
        f = A0.createVecLeft()
        A0.mult(x, f)
        xs.append(x), rs.append(r), loads.append(f if cases["forces"] is None else None)
        _log(mpi, f"case {k}: {iterations[-1]} iterations, true residual {residual:.1e}")
    solve = time.perf_counter() - t1
    if cases["forces"] is None:
        work = np.array([[g_dot(A, cases["values"][i], loads[j]) for j in range(6)]
                         for i in range(6)])
        stress_asym = max(_moment_asymmetry(mpi, loads[j], cases, x_local) for j in range(6))
    else:
        work = np.array([[g_dot(A, cases["forces"][i], xs[j]) for j in range(6)]
                         for i in range(6)])
        stress_asym = 0.0
    cross = np.array([[xs[i].dot(rs[j]) for j in range(6)] for i in range(6)])
    return {"work": work, "cross": cross, "iterations": iterations, "residuals": residuals,
            "setup_seconds": setup, "solve_seconds": solve, "warnings": warnings + (
                [f"PETSc options never used: {', '.join(unused)}"] if unused else []),
            "ksp_type": ksp.getType(), "pc_type": ksp.getPC().getType(),
            "rtol": float(ksp.getTolerances()[0]),
            "stress_asymmetry": float(stress_asym)}


def g_dot(A, local, vec):
    """Global dot product of a local array (this rank's rows) with a PETSc Vec."""
    v = A.createVecRight()
    v.setArray(local)
    return v.dot(vec)


def _moment_asymmetry(mpi, f, cases, x_local):
    """||M - M^T|| / ||M|| of the reaction moment M = sum_b f_b (x) x_b over the boundary."""
    nodes = np.unique(cases["dofs"] // 3)
    F = f.getArray().reshape(-1, 3)[nodes]
    M = mpi.allreduce(F.T @ x_local[nodes])
    return asymmetry(M)

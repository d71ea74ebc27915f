"""homogenize_bed: bed arrays in, effective elastic constants out (any rank count).

bed -> frame (largest component, non-dimensional) -> six load cases of a
boundary condition -> its averages -> C, S -> Ex, Ey, Ez, nu_yz, nu_xz, nu_xy,
G_yz, G_xz, G_xy. Each condition of :data:`BOUNDARY_CONDITIONS` names its
load-case groups and its average (docs/model.md, sections 5 and 9): KUBC and
mixed take C from the Bagi hull strain and the reaction stress, SUBC from
S = (1/V) F . U, periodic from the energy's dot products.
"""
import sys
import time
from collections import namedtuple

import numpy as np

from amfe.model.carrying import frame_warnings
from amfe.model.frame import build_frame
from amfe.model.averages import (asymmetry, bagi_strain, compliance_and_constants, hull_of,
                             stiffness, symmetric, voigt, voigt_strain)
from amfe.model.material import SOURCE_DEFAULT
from amfe.io.mpi import on_root
from amfe.io.fields import frame_fields
from amfe.io.result_meta import homogenize_header
from amfe.io.vtp import write_fields_vtp
from amfe.solvers.correction import (moment_corrections, never, relative_size,
                                     second_order_kubc, second_order_loads)
from amfe.solvers.choice import USER_METHOD_OPTIONS, choose_solver, cholesky_package, solve_features
from amfe.solvers.inputs import checked_inputs
from amfe.solvers.ksp import DEFAULT_RTOL, RESIDUAL_FACTOR
from amfe.model.kubc import kubc_groups
from amfe.solvers.loadcases import solve_load_cases
from amfe.model.mixed import mixed_groups
from amfe.model.periodic import periodic_average, periodic_groups
from amfe.model.subc import subc_average, subc_groups
from amfe.solvers.petsc import init_petsc, unused_options_warning


def bagi_average(frame, groups, u, moments, diagnose=False, cross=None):
    """KUBC and mixed: (C, V, stats) from the Bagi hull strains and reaction stresses.

    cross: per group D_ij = x_i . r_j or None; KUBC's (one group with its
    strains) corrects the moments to second order (:mod:`amfe.solvers.correction`).
    """
    hull = hull_of(frame.centers)
    stats = {}
    D = (cross or [None])[0]
    if D is not None and len(groups) == 1 and groups[0].strains is not None:
        dM = moment_corrections(groups[0].strains, D)
        if dM is not None:
            stats["correction"] = relative_size(dM, moments)
            moments = np.asarray(moments) + dM
    strains, stresses, stress_asym = [], [], []
    for k in range(6):
        strains.append(voigt_strain(bagi_strain(hull, u[k][:, :3])))
        sigma = moments[k] / frame.volume  # V: the bed's box; the strain stays the hull's
        stress_asym.append(asymmetry(sigma))
        stresses.append(voigt(symmetric(sigma)))
    C, c_asym = stiffness(np.array(strains), np.array(stresses))
    return C, frame.volume, {"stress_asymmetry": float(max(stress_asym)),
                            "C_asymmetry": float(c_asym), **stats}


#: name -> (groups(frame), average(frame, groups, u, moments, diagnose, cross), needs a
#: periodic bed, second_order(frame, groups): the corrected average is second order)
Condition = namedtuple("Condition", "groups average periodic second_order")
BOUNDARY_CONDITIONS = {"kubc": Condition(kubc_groups, bagi_average, False, second_order_kubc),
                       "mixed": Condition(mixed_groups, bagi_average, False, never),
                       "subc": Condition(subc_groups, subc_average, False, second_order_loads),
                       "periodic": Condition(periodic_groups, periodic_average, True,
                                             second_order_loads)}


def homogenize_bed(centers, radii, material=None, *, a_star_cap=None, rtol=None,
                   max_it=None, vtu_dir=None, comm=None, petsc_args=None, ksp_options=None,
                   nondimensional=True, bc="kubc", diagnose=False, progress=False, fields=False,
                   solver="gamg", box=None, accept_unconverged=False, max_memory=None,
                   material_source=None, input_error=None, size=None):
    """Effective elastic constants of a bed of bonded spheres.

    bc: "kubc" (default; six unit macro-strains on the boundary, one operator),
    "mixed" (the paper's figure-2 experiments, six operators; see
    :mod:`amfe.model.mixed`), "subc" (six unit macro-stresses as boundary
    loads, :mod:`amfe.model.subc`) or "periodic" (needs ``box`` (3,) [m], the
    periods of a periodic bed; :mod:`amfe.model.periodic`). diagnose: add a
    ``diagnostics`` list (per case: iterations, true residual, eigenvalue
    estimates of the preconditioned operator and their ratio, GAMG levels and
    complexities).

    centers (N,3) [m], radii (N,) [m]; every rank of ``comm`` (a PETSc or
    mpi4py communicator, default COMM_WORLD) passes bit-identical arrays,
    material and options: checked in one collective before anything else,
    a difference is an AmfeError on every rank (:mod:`amfe.solvers.inputs`).
    material: a :class:`~amfe.model.material.Material` (default: steel);
    material_source: where it came from, for the result (default "default
    (steel)" without a material, else "argument").
    Returns the result dict of docs/model.md, section 6 (the same on every rank):
    properties (SI: Pa and -), C and S (6x6, Voigt xx, yy, zz, yz, xz, xy,
    engineering shear; Pa and 1/Pa), volume [m^3], n_particles (input),
    n_removed, n_bonds, bc, ranks, solver (ksp_type, pc_type, rtol,
    residual_limit, iterations [6], setup_seconds, solve_seconds, plus
    residuals and the condition's checks, docs/model.md section 9), material
    (E, nu, psi, source) and warnings (list of str: accepted unconverged
    solves, PETSc options never used); with ``a_star_cap``, also n_capped. With
    ``vtu_dir``, rank 0 writes the ParaView files there (one .vtp per load case and
    cases.pvd; docs/viewing.md). The dict starts with the header of
    :func:`amfe.io.result_meta.homogenize_header` (input hash, material, box, counts, ...).
    ``ksp_options`` (dict) sets PETSc options for this solve only, e.g.
    {"ksp_type": "preonly", "pc_type": "cholesky"}; ``nondimensional=False``
    assembles in SI units (for the benchmark that shows why scaling matters).
    ``progress=True`` prints one line per phase and load case to stderr on rank 0.
    ``fields=True`` adds "fields": a :class:`~amfe.io.result.Fields` (every rank).
    ``solver``: "gamg" (CG + GAMG, rtol default 1e-8), "cholesky" (one rank) or
    "auto", the cheapest method that keeps the constants within 1e-5 of a tight
    reference (:mod:`amfe.solvers.choice`); the choice and its reason go into
    the result's ``solver`` record (method, reason).
    Every solve must reach a true relative residual of at most
    :data:`~amfe.solvers.ksp.RESIDUAL_FACTOR` x rtol (or x the rounding floor);
    ``accept_unconverged=True`` keeps the numbers of one that does not, with a
    warning. ``max_memory``: bytes the solve may take over all ranks (default:
    half the memory of the machines the ranks run on); a larger estimate is
    refused before any work. ``input_error``: an AmfeError the caller met
    preparing this rank's input, raised on every rank after the ranks are
    compared (so that no rank waits in a collective).
    ``size`` (3,) [m]: the bed's recorded box (attrs ``size``), whose volume is V
    (default: the spheres' bounding box; docs/model.md, section 5).
    Raises AmfeError on every rank for bad input or a failed solve.
    """
    PETSc = init_petsc(petsc_args)
    if comm is None:
        comm = PETSc.COMM_WORLD
    elif not isinstance(comm, PETSc.Comm):
        comm = PETSc.Comm(comm)  # an mpi4py communicator, e.g. a batch group
    mpi = comm.tompi4py()
    source = material_source or (SOURCE_DEFAULT if material is None else "argument")
    centers, radii, material, check_memory = checked_inputs(
        PETSc, mpi, centers, radii, material, bcs=BOUNDARY_CONDITIONS, bc=bc, rtol=rtol,
        max_it=max_it, a_star_cap=a_star_cap, ksp_options=ksp_options, max_memory=max_memory,
        input_error=input_error, box=box, nondimensional=nondimensional,
        diagnose=diagnose, accept_unconverged=accept_unconverged, solver=solver)
    t0 = time.perf_counter()
    log = _stderr_log(mpi.rank) if progress else None
    frame = build_frame(centers, radii, material, a_star_cap, nondimensional=nondimensional,
                        box=box if BOUNDARY_CONDITIONS[bc].periodic else None, bc=bc, size=size)
    t_frame = time.perf_counter() - t0
    groups = BOUNDARY_CONDITIONS[bc].groups(frame)
    # the same on every rank: rank 0 decides (qhull, ~0.06 s on 300 000 centres)
    corrected = correction_wanted(PETSc, ksp_options) and mpi.bcast(
        BOUNDARY_CONDITIONS[bc].second_order(frame, groups) if mpi.rank == 0 else None)
    if log:
        log(f"frame: {frame.n_particles} load-carrying particles ({frame.n_removed} removed), "
            f"{len(frame.bonds)} bonds in {t_frame:.2f} s; {bc}, {mpi.size} rank(s)")
    method, reason, rtol, options = choose_solver(
        lambda: solve_features(frame), mpi.size, solver, rtol, cholesky_package(PETSc),
        [k for k in USER_METHOD_OPTIONS
         if PETSc.Options().hasName(k) or k in (ksp_options or {})],
        singular=any(g.null_modes is not None for g in groups), check_memory=check_memory,
        corrected=corrected)
    if log:
        log(f"solver: {method} ({reason})")
    sol = solve_load_cases(PETSc, frame, comm, groups, rtol=DEFAULT_RTOL if rtol is None else rtol,
                           max_it=max_it, log=log, ksp_options={**options, **(ksp_options or {})},
                           diagnose=diagnose, accept_unconverged=accept_unconverged)
    warnings = sol.warnings
    if warnings and mpi.rank == 0:
        missed = [c for c in sol.cases if c.warning]
        print(f"amfe: warning: {len(missed)} load case(s) missed the convergence contract "
              f"(true relative residual <= {RESIDUAL_FACTOR:g} x rtol) and were kept as asked "
              "(accept_unconverged): " + ", ".join(f"{c.name} {c.residual:.1e}" for c in missed),
              file=sys.stderr, flush=True)
    # of the per-solve options, only the caller's count (not those the solver choice adds)
    unused = unused_options_warning(PETSc, mpi.rank, [
        n for n in sol.unused_options if n.lstrip("-") in {k.lstrip("-") for k in ksp_options or {}}])
    record = {"E": material.E, "nu": material.nu, "psi": material.psi, "source": source}
    result = on_root(mpi, _average, frame, groups, sol, bc, a_star_cap, mpi.size, t_frame,
                     vtu_dir, diagnose, fields, record, warnings + ([unused] if unused else []),
                     (centers, radii))
    result["solver"].update(method=method, reason=reason, requested=solver)
    return result


def correction_wanted(PETSc, ksp_options):
    """-amfe_correction (per solve or on the command line; default yes) is not "no".

    ``ksp_options`` keys may carry PETSc's dash, as the operator accepts them
    (:func:`amfe.solvers.ksp.petsc_options`): the two must read the same value.
    """
    given = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}.get("amfe_correction")
    return (given if given is not None
            else PETSc.Options().getString("amfe_correction", "yes")) != "no"


def _stderr_log(rank):
    start = time.perf_counter()

    def log(line):
        if rank == 0:
            print(f"[{time.perf_counter() - start:7.2f} s] {line}", file=sys.stderr, flush=True)
    return log


def _average(frame, groups, sol, bc, a_star_cap, ranks, t_frame, vtu_dir, diagnose, fields,
             material, warnings, bed):
    """Rank 0: the condition's averages, C, S, constants, the result dict (and the ParaView
    files). ``bed``: (centers, radii), the input arrays."""
    t0 = time.perf_counter()
    C, volume, stats = BOUNDARY_CONDITIONS[bc].average(frame, groups, sol.u, sol.moments,
                                                       diagnose=diagnose, cross=sol.cross)
    C = C * frame.stress_scale
    S, props = compliance_and_constants(C)
    for line in frame_warnings(frame, bc):   # removed pieces, the box rule: on the terminal too
        print(f"amfe: warning: {line}", file=sys.stderr, flush=True)
    t_avg = time.perf_counter() - t0
    result = {
        "properties": {k: float(v) for k, v in props.items()},
        "C": C.tolist(),
        "S": S.tolist(),
        "volume": float(volume * frame.length_scale**3),
        "n_particles": int(frame.n_input),
        "n_removed": int(frame.n_removed),
        "removed": frame.removed,
        "n_bonds": int(len(frame.bonds)),
        "bc": bc,
        "ranks": int(ranks),
        "solver": {
            "ksp_type": sol.setups[0].ksp_type, "pc_type": sol.setups[0].pc_type,
            "rtol": sol.setups[0].rtol, "residual_limit": RESIDUAL_FACTOR * sol.setups[0].rtol,
            "norm_type": sol.setups[0].norm_type,
            "iterations": sol.iterations,
            "setup_seconds": sol.setup_seconds, "solve_seconds": sol.solve_seconds,
            "case_seconds": [c.seconds for c in sol.cases],
            "frame_seconds": t_frame, "assembly_seconds": sol.assembly_seconds,
            "average_seconds": t_avg,
            "residuals": sol.residuals,
            **stats,
        },
        "material": material,
        "warnings": list(warnings) + frame_warnings(frame, bc),
    }
    result = {**homogenize_header(frame, bed[0], bed[1], material), **result}
    if sol.notes:
        result["solver"]["notes"] = sol.notes
    if a_star_cap is not None:
        result["n_capped"] = int(frame.n_capped)
    if diagnose:
        result["diagnostics"] = sol.diagnostics()
    if fields or vtu_dir is not None:
        f = frame_fields(frame, sol.u, groups, bc, centers=bed[0], radii=bed[1])
    if fields:
        result["fields"] = f
    if vtu_dir is not None:
        paths = write_fields_vtp(vtu_dir, f)
        result["vtk"] = {"collection": paths[-1], "files": paths[:-1]}
    return result


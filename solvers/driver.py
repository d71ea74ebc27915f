"""homogenize_bed: bed arrays in, effective elastic constants out (any rank count).

bed -> frame (largest component, non-dimensional) -> six load cases of a
boundary condition -> its averages -> C, S -> Ex, Ey, Ez, nu_yz, nu_xz, nu_xy,
G_yz, G_xz, G_xy. Each condition of the table (:mod:`amfe.model.conditions`)
names its load-case groups and its average (docs/model.md, sections 5 and 9),
which the driver looks up by the condition's name: KUBC and mixed take C from the
Bagi hull strain and the reaction stress (:func:`bagi_average`, here), SUBC from
S = (1/V) F . U, periodic from the energy's dot products.
"""
import logging
import time
from collections import namedtuple
from dataclasses import replace

import numpy as np

from amfe.errors import AmfeError
from amfe.io.fields import frame_fields
from amfe.io.mpi import on_root
from amfe.io.result import Result
from amfe.io.result_meta import homogenize_header
from amfe.model.averages import (
    asymmetry,
    bagi_strain,
    compliance_and_constants,
    hull_of,
    stiffness,
    symmetric,
    voigt,
    voigt_strain,
)
from amfe.model.bed import Bed
from amfe.model.carrying import frame_warnings
from amfe.model.conditions import CONDITIONS, get_condition, solver_part
from amfe.model.continuum_springs import (
    apply_springs,
    resolve_springs,
    springs_record,
    springs_warnings,
)
from amfe.model.frame import FRAME_LOG, build_frame
from amfe.model.options import SolveOptions
from amfe.model.volumebox import unit_warnings, volume_box_record
from amfe.solvers.adjoint import attach_strain_adjoint
from amfe.solvers.choice import (
    USER_METHOD_OPTIONS,
    Problem,
    cholesky_package,
    choose_solver,
    shown_method,
    solve_features,
)
from amfe.solvers.correction import (
    STRAIN_ADJOINT_DEFAULT,
    free_strain_share,
    moment_corrections,
    relative_size,
)
from amfe.solvers.inputs import checked_inputs, given_options, given_size
from amfe.solvers.ksp import DEFAULT_RTOL, RESIDUAL_FACTOR
from amfe.solvers.loadcases import solve_load_cases
from amfe.solvers.mgchoice import CHOSEN_OPTIONS, choose_multigrid, multigrid_features
from amfe.solvers.options import call_options
from amfe.solvers.petsc import unused_options_warning
from amfe.solvers.petsclib import PETSc
from amfe.solvers.progress import Progress

LOG = logging.getLogger("amfe.solvers")


def bagi_average(frame, groups, u, moments, diagnose=False, cross=None, strain_cross=None):
    """KUBC and mixed: (C, V, stats) from the Bagi hull strains and reaction stresses.

    cross: per group D_ij = x_i . r_j or None; KUBC's (one group with its
    strains) corrects the moments to second order (:mod:`amfe.solvers.correction`).
    strain_cross: (6, 6) G_mj = z_m . r_j of the strain's adjoints (free hull vertices,
    :mod:`amfe.solvers.adjoint`), added to case j's Voigt strain.
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
        if strain_cross is not None:
            dE = np.asarray(strain_cross)[:, k]
            stats["strain_correction"] = max(stats.get("strain_correction", 0.0), float(
                np.linalg.norm(dE) / (np.linalg.norm(strains[-1]) or 1.0)))
            strains[-1] = strains[-1] + dE
        sigma = moments[k] / frame.volume  # V: the bed's box; the strain stays the hull's
        stress_asym.append(asymmetry(sigma))
        stresses.append(voigt(symmetric(sigma)))
    C, c_asym = stiffness(np.array(strains), np.array(stresses))
    return C, frame.volume, {"stress_asymmetry": float(max(stress_asym)),
                            "C_asymmetry": float(c_asym), **stats}


def homogenize_bed(bed: Bed, options: SolveOptions | None = None, comm: object = None, *,
                   input_error: AmfeError | None = None) -> Result:
    """Effective elastic constants of a bed of bonded spheres, as a :class:`Result`.

    bed: a checked :class:`~amfe.model.bed.Bed` (centres (N, 3) [m], radii (N,)
    [m]; ``attrs["periodic"]``, the box (3,) [m] of a periodic bed, for
    bc="periodic"). options: a :class:`~amfe.model.options.SolveOptions`
    (default: its defaults), checked when it was made: bc "kubc" (six unit
    macro-strains on the boundary, one operator), "mixed" (the paper's
    figure-2 experiments, :mod:`amfe.model.mixed`), "subc" (six unit
    macro-stresses as boundary loads, :mod:`amfe.model.subc`) or "periodic"
    (:mod:`amfe.model.periodic`); its material (None: the bed's, else steel).
    comm: a PETSc or mpi4py communicator (default COMM_WORLD); every rank
    passes a bit-identical bed and options: checked in one collective before
    anything else, a difference is an AmfeError on every rank
    (:mod:`amfe.solvers.inputs`). ``input_error``: an AmfeError the caller met
    preparing this rank's bed or options (then ``bed`` and ``options`` may be
    None), raised on every rank after the ranks are compared (so that no rank
    waits in a collective).

    Returns the :class:`~amfe.io.result.Result` of docs/model.md, section 6 (the
    same on every rank), whose ``to_dict()`` starts with the header of
    :func:`amfe.io.result_meta.homogenize_header`: properties (SI: Pa and -), C
    and S (6x6, Voigt xx, yy, zz, yz, xz, xy, engineering shear; Pa and 1/Pa),
    volume [m^3], counts, bc, ranks, solver (ksp_type, pc_type, rtol,
    residual_limit, iterations [6], times, residuals and the condition's checks,
    docs/model.md section 9; method and reason of the solver choice,
    :mod:`amfe.solvers.choice`; multigrid: GAMG's aggregation,
    :mod:`amfe.solvers.mgchoice`), material (E, nu, psi, source) and warnings (list
    of str: accepted unconverged solves, PETSc options never used); with
    ``a_star_cap``, n_capped; with ``diagnose``, diagnostics (per case:
    iterations, true residual, eigenvalue estimates, GAMG levels and
    complexities). ``fields=True``: ``result.fields``, a
    :class:`~amfe.io.result.Fields` on every rank ("root": on rank 0 only, for
    the files the caller writes).

    Progress (one line per phase and load case; on beds above
    :data:`~amfe.solvers.progress.PROGRESS_PARTICLES` also each phase's start and the time
    left) and warnings leave through the ``logging`` logger "amfe.solvers", on rank 0 only;
    this function prints and writes nothing. Every solve must reach a true relative
    residual of at most :data:`~amfe.solvers.ksp.RESIDUAL_FACTOR` x rtol (or x the rounding floor);
    ``accept_unconverged`` keeps the numbers of one that does not, with a
    warning. The bed's recorded box (``attrs["size"]`` (3,) [m]) is V (else the
    load-carrying spheres' bounding box; docs/model.md, section 5).
    Raises AmfeError on every rank for bad input or a failed solve.
    Changed in 0.3.0: it took the arrays and some twenty keyword options and
    returned a dict.
    """
    if options is None and input_error is None:
        options = SolveOptions()
    # this call's PETSc options, in the database for this call alone (amfe.solvers.options)
    with call_options(options.petsc_args if isinstance(options, SolveOptions) else ()) as scope:
        return _homogenize(bed, options, comm, input_error, scope)


def _homogenize(bed, options, comm, input_error, scope):
    """:func:`homogenize_bed` inside its :func:`~amfe.solvers.options.call_options`."""
    comm = petsc_comm(comm)
    mpi = comm.tompi4py()
    inp = checked_inputs(mpi, bed, options, CONDITIONS, input_error)
    options, condition = inp.options, get_condition(inp.options.bc)
    # the parameter file read once a solve: the frame, the record and the warning share it
    options = replace(options, springs=resolve_springs(options.springs) or "paper")
    t0 = time.perf_counter()
    log = Progress(_progress(mpi.rank), len(bed.centers))   # long solves: each phase's start
    log.phase("frame", f"frame: building it from {len(bed.centers)} particles "
              "(contacts, load-carrying part, springs)")
    token = FRAME_LOG.set(log.log if log.long else None)
    try:
        frame = build_frame(bed.centers, bed.radii, inp.material, options.a_star_cap,
                            nondimensional=options.nondimensional,
                            box=inp.box if condition.periodic else None, bc=options.bc,
                            size=given_size(bed, options))
        frame = apply_springs(frame, options.springs)   # "paper": the frame as built
    finally:
        FRAME_LOG.reset(token)
    t_frame = time.perf_counter() - t0
    groups = condition.groups(frame)
    log.n_cases = sum(len(g.names) for g in groups)
    # the same on every rank: rank 0 decides (qhull; docs/benchmarks.md, "Figures quoted ...")
    corrected = correction_wanted(options.ksp_options) and mpi.bcast(
        solver_part(condition.second_order)(frame, groups) if mpi.rank == 0 else None)
    adjoint = False
    if (correction_wanted(options.ksp_options) and not corrected and condition.hull_strain
            and strain_adjoint_wanted(options.ksp_options)):
        adjoint = corrected = attach_strain_adjoint(frame, groups, mpi)  # free hull vertices
    problem = Problem(singular=any(g.null_modes is not None for g in groups), corrected=corrected,
                      free_share=_free_share(frame, groups, condition, corrected, options, mpi))
    log(f"frame: {frame.n_particles} load-carrying particles ({frame.n_removed} removed), "
        f"{len(frame.bonds)} bonds in {t_frame:.2f} s; {options.bc}, {mpi.size} rank(s)")
    method, reason, rtol, chosen = choose_solver(
        lambda: solve_features(frame), mpi.size, options.solver, options.rtol,
        cholesky_package(),
        given_options(USER_METHOD_OPTIONS, options.ksp_options),
        problem, check_memory=inp.check_memory)
    log(f"solver: {shown_method(method, options.ksp_options)} ({reason})")
    multigrid = None
    if method == "gamg":  # aggregation per bed (:mod:`amfe.solvers.mgchoice`)
        mg_options, mg_reason = choose_multigrid(
            # the adjoints' beds stay smoothed: unsmoothed aggregation at rtol 1e-5 left paper 301
            # 2.1e-5 from the reference (docs/benchmarks.md, "The strain to second order")
            multigrid_features(frame), mpi.size, corrected and not adjoint,
            given_options(CHOSEN_OPTIONS, options.ksp_options),
            loosened=problem.loosened)
        chosen, multigrid = {**chosen, **mg_options}, {"options": mg_options, "reason": mg_reason}
        log(f"multigrid: {mg_reason}")
    sol = solve_load_cases(frame, comm, groups, rtol=DEFAULT_RTOL if rtol is None else rtol,
                           max_it=options.max_it, log=log,
                           ksp_options={**chosen, **options.ksp_options},
                           diagnose=options.diagnose,
                           accept_unconverged=options.accept_unconverged)
    warnings = sol.warnings
    if warnings and mpi.rank == 0:
        missed = [c for c in sol.cases if c.warning]
        LOG.warning(f"{len(missed)} load case(s) missed the convergence contract "
                    f"(true relative residual <= {RESIDUAL_FACTOR:g} x rtol) and were kept as "
                    "asked (accept_unconverged): "
                    + ", ".join(f"{c.name} {c.residual:.1e}" for c in missed))
    # of the per-solve options, only the caller's count (not those the solver choice adds)
    mine = {k.lstrip("-") for k in options.ksp_options}
    unused = unused_options_warning(mpi.rank,
                                    [n for n in sol.unused_options if n.lstrip("-") in mine],
                                    names=scope.unused())
    ignored = scope.ignored_warning(mpi.rank)
    solved = Solved(frame, groups, sol, t_frame, mpi.size, inp.record,
                    warnings + [w for w in (unused, ignored) if w], bed)
    d = on_root(mpi, _average, solved, options)
    d["solver"].update(method=method, reason=reason, requested=options.solver)
    if multigrid is not None:
        d["solver"]["multigrid"] = multigrid
    fields = None
    if options.fields == "root":
        fields = _fields(solved, options.bc) if mpi.rank == 0 else None
    elif options.fields:
        fields = on_root(mpi, _fields, solved, options.bc)
    return Result.from_dict(d, fields=fields)


def petsc_comm(comm):
    """The PETSc communicator of ``comm``: None (COMM_WORLD), a PETSc or an mpi4py one (e.g. a
    batch group's); AmfeError naming comm for anything else."""
    if comm is None:
        return PETSc.COMM_WORLD
    if isinstance(comm, PETSc.Comm):
        return comm
    try:
        return PETSc.Comm(comm)
    except TypeError:
        raise AmfeError(f"comm must be an mpi4py or PETSc communicator, got "
                        f"{type(comm).__name__} {comm!r}") from None


def _free_share(frame, groups, condition, corrected, options, mpi):
    """The free hull vertices' share of KUBC's strain on a first-order bed (rank 0's, on every
    rank), or None: another condition, a second-order bed, the user's own rtol, or the user's
    own aggregation (the share's rtol rule was measured with smoothed aggregation)."""
    if (corrected or not condition.hull_strain
            or options.rtol is not None or not correction_wanted(options.ksp_options)
            or given_options(("pc_gamg_agg_nsmooths",), options.ksp_options)):
        return None
    return mpi.bcast(free_strain_share(frame, groups) if mpi.rank == 0 else None)


def correction_wanted(ksp_options):
    """-amfe_correction (per solve or on the command line; default yes) is not "no".

    ``ksp_options`` keys may carry PETSc's dash, as the operator accepts them
    (:func:`amfe.solvers.ksp.petsc_options`): the two must read the same value.
    """
    given = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}.get("amfe_correction")
    return (given if given is not None
            else PETSc.Options().getString("amfe_correction", "yes")) != "no"


def strain_adjoint_wanted(ksp_options):
    """-amfe_strain_adjoint (as -amfe_correction): yes or no, default
    :data:`~amfe.solvers.correction.STRAIN_ADJOINT_DEFAULT`; AmfeError for another value."""
    given = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}.get("amfe_strain_adjoint")
    value = (given if given is not None else PETSc.Options().getString(
        "amfe_strain_adjoint", STRAIN_ADJOINT_DEFAULT))
    if value not in ("yes", "no"):
        raise AmfeError(f"-amfe_strain_adjoint {value!r}: give yes (the strain to second order "
                        "on beds with free hull vertices) or no")
    return value == "yes"


def _progress(rank):
    """log(line): one progress line to the logger, on rank 0 only (the face decides what
    prints, :func:`amfe.api.homogenize`)."""
    def log(line):
        if rank == 0:
            LOG.info(line)
    return log


#: What the solve gives the averages (rank 0): the frame, its groups, the solutions, the
#: frame's time [s], the rank count, the material record, the warnings and the input bed.
Solved = namedtuple("Solved", "frame groups sol t_frame ranks material warnings bed")


def _fields(solved, bc):
    """Rank 0: the per-case fields (:func:`amfe.io.fields.frame_fields`)."""
    return frame_fields(solved.frame, solved.sol.u, solved.groups, bc,
                        centers=solved.bed.centers, radii=solved.bed.radii)


def _average(solved, options):
    """Rank 0: the condition's averages, C, S, constants: the result dict."""
    frame, groups, sol = solved.frame, solved.groups, solved.sol
    t0 = time.perf_counter()
    G = sol.setups[0].strain_cross
    C, volume, stats = solver_part(get_condition(options.bc).average)(
        frame, groups, sol.u, sol.moments, diagnose=options.diagnose, cross=sol.cross,
        **({} if G is None else {"strain_cross": G}))
    if G is not None:
        stats.update(adjoint_iterations=sol.setups[0].adjoint_iterations,
                     adjoint_seconds=sol.setups[0].adjoint_seconds)
    C = C * frame.stress_scale
    S, props = compliance_and_constants(C)
    size = np.asarray(frame.size) * frame.length_scale
    warnings = (frame_warnings(frame, options.bc) + unit_warnings(solved.bed.radii, size)
                + springs_warnings(frame, options.springs))
    for line in warnings:   # removed pieces, the box rule, the unit: the terminal
        LOG.warning(line)
    t_avg = time.perf_counter() - t0
    result = {
        "properties": {k: float(v) for k, v in props.items()},
        "C": C.tolist(),
        "S": S.tolist(),
        "volume": float(volume * frame.length_scale**3),
        "volume_box": volume_box_record(frame.box_lo, size, frame.box_source, frame.box_note),
        "n_particles": int(frame.n_input),
        "n_removed": int(frame.n_removed),
        "removed": frame.removed,
        "n_bonds": int(len(frame.bonds)),
        "bc": options.bc,
        "ranks": int(solved.ranks),
        "solver": {
            "ksp_type": sol.setups[0].ksp_type, "pc_type": sol.setups[0].pc_type,
            "rtol": sol.setups[0].rtol, "residual_limit": RESIDUAL_FACTOR * sol.setups[0].rtol,
            "norm_type": sol.setups[0].norm_type,
            "iterations": sol.iterations,
            "setup_seconds": sol.setup_seconds, "solve_seconds": sol.solve_seconds,
            "case_seconds": [c.seconds for c in sol.cases],
            "frame_seconds": solved.t_frame, "assembly_seconds": sol.assembly_seconds,
            "average_seconds": t_avg,
            "residuals": sol.residuals,
            **stats,
        },
        "material": solved.material,
        "springs": springs_record(options.springs),
        "warnings": list(solved.warnings) + warnings,
    }
    bed = solved.bed
    result = {**homogenize_header(frame, bed.centers, bed.radii, solved.material), **result}
    if sol.notes:
        result["solver"]["notes"] = sol.notes
    if options.a_star_cap is not None:
        result["n_capped"] = int(frame.n_capped)
    if options.diagnose:
        result["diagnostics"] = sol.diagnostics()
    return result

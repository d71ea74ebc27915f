"""amfe's Python face: :func:`homogenize` a bed (object, file or arrays) into a :class:`Result`.

The functions here only gather the input and hand it to the layers below
(docs/model.md, section 1): the bed is read (on rank 0 under MPI, then
broadcast), the frame built, the load cases solved with PETSc, and the Bagi
averages turned into the constants.
"""
import logging
import os
from dataclasses import replace

from amfe.errors import AmfeError
from amfe.io.console import LOGGER, messages
from amfe.io.mpi import on_root, same_on_every_rank
from amfe.io.result import Result
from amfe.io.result_meta import describe_input
from amfe.io.vtu import write_fields_vtu
from amfe.io.vtuset import clear_stale_sets
from amfe.model.bed import Bed
from amfe.model.conditions import CONDITIONS, condition_names
from amfe.model.continuum_springs import fraction_warnings
from amfe.model.material import Material, resolve_material
from amfe.model.options import SolveOptions, check_choice, check_flag, check_petsc_options


def homogenize(bed: Bed | str | os.PathLike | tuple, *, bc: str = "kubc",
               rtol: float | None = None, comm: object = None, fields: bool = False,
               petsc_options: dict | None = None, a_star_cap: float | None = None,
               material: Material | dict | None = None, max_it: int | None = None,
               diagnose: bool = False, progress: bool = False,
               vtu_dir: str | os.PathLike | None = None, solver: str = "auto",
               accept_unconverged: bool = False, max_memory: float | str | None = None,
               material_source: str | None = None, input_path: str | os.PathLike | None = None,
               model: str = "frame", voxel_size: float | None = None,
               voxel_operator: str = "assembled",
               box: tuple | None = None, springs: str = "paper") -> Result | dict[str, Result]:
    """Effective elastic constants of a powder bed, as a :class:`~amfe.io.result.Result`.

    Parameters
    ----------
    bed : Bed, str or path-like, or (centers, radii)
        The bed: an :class:`amfe.Bed`, the path of a bed file (read on rank 0
        and broadcast), or arrays centers (N, 3) [m] and radii (N,) [m] of
        real numbers that must be bit-identical on every rank (checked; a
        difference is an error on every rank).
    bc : {"kubc", "mixed", "subc", "periodic", "all"}
        Boundary conditions (docs/model.md, sections 5 and 9). "periodic"
        needs a periodic bed (``generate_bed(..., periodic=True)``, whose
        attrs carry ``periodic``). "all" solves KUBC and SUBC (and periodic
        on a periodic bed) and returns a dict {bc: Result}, VTU files in
        ``vtu_dir``/<bc>.
    rtol : float, optional
        GAMG's relative residual tolerance. Default: 1e-5 for KUBC on a bed
        whose hull vertices are all prescribed (the reaction stress is then
        corrected to second order in the solver's error, docs/model.md
        section 5) or whose free hull vertices carry at most 1e-3 of the
        strain (docs/model.md section 5, "Free hull vertices that weigh
        little"); otherwise 1e-8 with ``solver="gamg"``, 1e-7 for the beds
        ``"auto"`` gives to GAMG.
    comm : mpi4py or PETSc communicator, optional
        The ranks that share the solve (default: all of them).
    fields : bool
        Also return the per-case displacements, rotations and bond forces
        (``result.fields``, an :class:`amfe.io.result.Fields`).
    petsc_options : dict, optional
        PETSc options for this solve only, e.g. ``{"ksp_monitor": None}``.
    a_star_cap : float, optional
        Cap every bond's a* at this value instead of refusing near-critical bonds.
    material : Material or dict, optional
        The particles' material. A :class:`Material` replaces the bed's; a
        dict of some of E [Pa], nu, psi overrides those of the bed file (whose
        E, nu, psi must otherwise be complete or absent). Default: the bed
        file's, else steel. ``result.extra["material"]`` says which was used.
    max_it : int, optional
        Iteration limit of each solve.
    diagnose, progress : bool
        Add per-case solver diagnostics; print progress lines to stderr.
    vtu_dir : str, optional
        Write the ParaView files there: one .vtu per load case, cases.json and cases.pvd
        (docs/viewing.md); with bc="all", one subdirectory per condition.
    solver : {"auto", "gamg", "cholesky"}
        How to solve: ``"auto"`` picks per bed the cheapest method whose
        constants stay within 1e-5 of a tight reference (Cholesky on one rank
        where the predicted fill is low, else CG + GAMG); ``result.solver``
        says which and why.
    accept_unconverged : bool
        Keep the numbers of a solve that misses its tolerance (true relative
        residual above 10 x rtol), with a warning in ``result.extra["warnings"]``,
        instead of raising AmfeError.
    max_memory : float, optional
        Bytes reading and solving may take, over all ranks (default: half the
        machine's memory); a larger estimate is refused before any work.
    material_source : str, optional
        What to call the given material's origin in the result (default
        "argument"; the CLI says "command line").
    input_path : str, optional
        The bed file to name in the result's ``input`` block (default: ``bed``
        itself when it is a path).
    model : {"frame", "voxel"}
        "frame" (default): the paper's bonded space frame. "voxel": the
        continuum of the same spheres by voxel finite elements, the frame's
        reference (docs/model.md, section 10); bc "kubc" or "periodic" only.
    voxel_size : float, optional
        The voxel model's voxel side [m] (default: mean radius / 4).
    voxel_operator : {"assembled", "matrix-free"}
        The voxel model's stiffness: an assembled AIJ matrix with GAMG
        (default), or applied element by element with a two-grid
        preconditioner, a few kB a node instead of about 16 (docs/model.md,
        section 10, "Matrix-free operator").
    box : (Lx, Ly, Lz), optional
        V's box [m], as you state it (the command line's ``--box``), checked to
        hold the load-carrying centres and centred on them; default: the bed's
        recorded size, else the load-carrying spheres' bounding box
        (docs/model.md, section 5). ``result.extra["volume_box"]`` says which
        box V is and where it came from; ``result.extra["density"]`` is the
        solid fraction of that box (relative density, to 1e-3).
    springs : {"paper", "continuum"}
        The frame's bond springs: the paper's eqs. 1-4 (default), or those
        calibrated on the voxel model's continuum (docs/model.md, section 11;
        frame model only). ``result.extra["springs"]`` records which, with the
        fitted parameters.

    Returns
    -------
    Result (a dict {bc: Result} for bc="all")
        C, S, the nine constants (also as attributes: ``result.Ex``), volume,
        counts, the solver record, ``extra["material"]`` and ``extra["warnings"]``.

    Examples
    --------
    >>> import amfe
    >>> bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)
    >>> result = amfe.homogenize(bed, rtol=1e-10)
    >>> round(result.Ex / 1e9), round(result.nu_xy, 3)   # Pa -> GPa
    (90, 0.086)
    >>> result.C.shape
    (6, 6)
    """
    from amfe.dataset.density import result_density  # noqa: PLC0415 (scipy: a solve's)
    from amfe.solvers.driver import homogenize_bed, petsc_comm

    check_flag("progress", progress)
    for name, value in (("vtu_dir", vtu_dir), ("input_path", input_path)):
        if value is not None and not isinstance(value, (str, os.PathLike)):
            raise AmfeError(f"homogenize: {name} must be a path (str) or None, got "
                            f"{type(value).__name__} {value!r}")
    if material_source is not None and not isinstance(material_source, str):
        raise AmfeError(f"homogenize: material_source must be a str, got {material_source!r}")
    check_choice("bc", bc, condition_names() + ("all",))
    pcomm = petsc_comm(comm)
    mpi = pcomm.tompi4py()
    # Collective, before the first collective that depends on them: a path on one rank and
    # a Bed on another would pair on_root's bcast with the input check's allgather.
    same_on_every_rank(mpi, {"bed": repr(os.fspath(bed)) if isinstance(bed, (str, os.PathLike))
                             else "an amfe.Bed or arrays", "max_memory": repr(max_memory)})
    options = error = None
    try:  # a failure here on one rank only must still reach the collective check
        options = SolveOptions(
            rtol=rtol, solver=solver, max_it=max_it, a_star_cap=a_star_cap,
            ksp_options=check_petsc_options("petsc_options", petsc_options),
            accept_unconverged=accept_unconverged, max_memory=max_memory, diagnose=diagnose,
            box=box, springs=springs,
            fields=check_flag("fields", fields) or ("root" if vtu_dir is not None else False))
        if isinstance(bed, (str, os.PathLike)):
            input_path = bed if input_path is None else input_path
            from amfe.io.bedfile import read_bed
            bed = on_root(mpi, read_bed, bed, max_memory=options.max_memory)
        bed, material, source = _inputs(bed, material, material_source or "argument")
        options = replace(options, material=material, material_source=source)
    except AmfeError as exc:
        error = exc

    def with_density(result):
        result.extra["density"] = result_density(bed.centers, bed.radii,
                                                 result.extra["volume_box"],
                                                 options.material.density)
        # the continuum springs' range is one of solid fraction, known only now
        for line in fraction_warnings(result.extra["density"]["solid_fraction"],
                                      options.springs):
            result.extra.setdefault("warnings", []).append(line)
            if mpi.rank == 0:
                logging.getLogger(LOGGER).warning(line)
        return result

    # --- voxel model dispatch (issue 35): its own solver, nothing of the frame's path ---
    if model != "frame" or voxel_size is not None or voxel_operator != "assembled":
        return with_density(_voxel(bed, options, error, pcomm,
                                   dict(bc=bc, model=model, voxel_size=voxel_size,
                                        progress=progress, vtu_dir=vtu_dir,
                                        input_path=input_path, operator=voxel_operator)))

    def one(bc, vtu_dir):
        with messages(progress):
            result = homogenize_bed(bed, options and replace(options, bc=bc), pcomm,
                                    input_error=error)
        describe_input(result.extra, input_path)
        with_density(result)
        if vtu_dir is not None:
            paths = on_root(mpi, write_fields_vtu, vtu_dir, result.fields)
            result.extra["vtk"] = {"collection": paths[-1], "files": paths[:-1]}
            if not fields:
                result.fields = None
        return result
    if bc != "all":
        return one(bc, vtu_dir)
    periodic_bed = error is None and "periodic" in bed.attrs
    names = [n for n, c in CONDITIONS.items() if c.in_all and (periodic_bed or not c.periodic)]
    results = {name: one(name, vtu_dir and os.path.join(vtu_dir, name)) for name in names}
    if vtu_dir is not None:   # an older set beside the new one: `amfe view` must not find it
        on_root(mpi, clear_stale_sets, vtu_dir, names)
    return results


def _voxel(bed, options, error, comm, spec):
    """The voxel model's Result (issue 35; docs/model.md, section 10).

    spec: the face's bc, model, voxel_size, progress, vtu_dir, input_path and operator."""
    from amfe.solvers.voxel import homogenize_voxel
    bc, model = spec["bc"], spec["model"]
    if error is None and options.solver not in ("auto", "gamg"):
        raise AmfeError("homogenize: the voxel model solves with CG + GAMG, not "
                        f"{options.solver!r}")
    if model != "voxel":
        raise AmfeError(f"homogenize: model must be 'frame' or 'voxel', got {model!r}"
                        + ("" if model != "frame" else
                           " (voxel_size and voxel_operator need model='voxel')"))
    if bc not in ("kubc", "periodic"):
        raise AmfeError(f"homogenize: the voxel model solves bc 'kubc' or 'periodic', not {bc!r}")
    if spec["vtu_dir"] is not None:
        raise AmfeError("homogenize: the voxel model writes no ParaView files yet (no --vtu)")
    if error is None and options.a_star_cap is not None:   # issue 45 fuzz: was ignored
        raise AmfeError("homogenize: the a* cap (--cap-a-star) caps the frame's springs; the "
                        "voxel model has none: leave it out, or give --model frame")
    if error is None and options.springs != "paper":
        raise AmfeError("homogenize: the springs (--springs) are the frame's; the voxel model is "
                        "the continuum itself: leave it out, or give --model frame")
    if error is None and options.diagnose:
        raise AmfeError("homogenize: --diagnose describes the frame's solve; the voxel model "
                        "has no diagnostics: leave it out, or give --model frame")
    with messages(spec["progress"]):
        result = homogenize_voxel(bed, options and replace(options, bc=bc), comm,
                                  voxel_size=spec["voxel_size"], input_error=error,
                                  operator=spec["operator"])
    describe_input(result.extra, spec["input_path"])
    return result


def _inputs(bed, material, given_source):
    """(Bed, Material, its source) of the arguments: the bed checked, the material resolved."""
    if isinstance(bed, (tuple, list)) and len(bed) == 2:
        bed = Bed(*bed)
    elif not isinstance(bed, Bed):
        raise AmfeError("homogenize: bed must be an amfe.Bed, a bed file's path, or "
                        f"(centers, radii); got {type(bed).__name__}")
    if isinstance(material, Material):
        return bed, material, given_source
    if material is not None and not isinstance(material, dict):
        raise AmfeError("homogenize: material must be an amfe.Material or a dict of E, nu, "
                        f"psi; got {type(material).__name__}")
    material, record = resolve_material(bed.attrs, material, given_source=given_source)
    return bed, material, record["source"]

"""amfe's Python face: :func:`homogenize` a bed (object, file or arrays) into a :class:`Result`.

The functions here only gather the input and hand it to the layers below
(docs/model.md, section 1): the bed is read (on rank 0 under MPI, then
broadcast), the frame built, the load cases solved with PETSc, and the Bagi
averages turned into the constants.
"""
import os

from amfe.errors import AmfeError
from amfe.io.mpi import on_root
from amfe.io.result import Result
from amfe.io.result_meta import describe_input, material_source


def homogenize(bed, *, bc="kubc", rtol=None, comm=None, fields=False, petsc_options=None,
               a_star_cap=None, material=None, max_it=None, diagnose=False, progress=False,
               vtu_dir=None, input_path=None):
    """Effective elastic constants of a powder bed, as a :class:`~amfe.io.result.Result`.

    Parameters
    ----------
    bed : Bed, str or path-like, or (centers, radii)
        The bed: an :class:`amfe.Bed`, the path of a bed file (read on rank 0
        and broadcast), or arrays centers (N, 3) [m] and radii (N,) [m] that
        must be the same on every rank.
    bc : {"kubc", "mixed"}
        Boundary conditions (docs/model.md, section 5).
    rtol : float, optional
        Relative residual tolerance of the solves (default 1e-8).
    comm : mpi4py or PETSc communicator, optional
        The ranks that share the solve (default: all of them).
    fields : bool
        Also return the per-case displacements, rotations and bond forces
        (``result.fields``, an :class:`amfe.io.result.Fields`).
    petsc_options : dict, optional
        PETSc options for this solve only, e.g. ``{"ksp_monitor": None}``.
    a_star_cap : float, optional
        Cap every bond's a* at this value instead of refusing near-critical bonds.
    material : Material, optional
        The particles' material; default: the bed file's, else steel.
    max_it : int, optional
        Iteration limit of each solve.
    diagnose, progress : bool
        Add per-case solver diagnostics; print progress lines to stderr.
    vtu_dir : str, optional
        Write the ParaView files there: one .vtp per load case and cases.pvd
        (docs/viewing.md).
    input_path : str, optional
        The bed file to name in the result's ``input`` block (default: ``bed``
        itself when it is a path).

    Returns
    -------
    Result
        C, S, the nine constants (also as attributes: ``result.Ex``), volume,
        counts and the solver record.

    Examples
    --------
    >>> import amfe
    >>> bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)
    >>> result = amfe.homogenize(bed, rtol=1e-10)
    >>> round(result.Ex / 1e9), round(result.nu_xy, 3)   # Pa -> GPa
    (729, 0.086)
    >>> result.C.shape
    (6, 6)
    """
    from amfe.model.bed import Bed
    from amfe.solvers.driver import homogenize_bed
    from amfe.solvers.ksp import DEFAULT_RTOL
    from amfe.solvers.petsc import init_petsc

    PETSc = init_petsc()
    pcomm = PETSc.COMM_WORLD if comm is None else (
        comm if isinstance(comm, PETSc.Comm) else PETSc.Comm(comm))
    mpi = pcomm.tompi4py()
    if isinstance(bed, (str, os.PathLike)):
        input_path = bed if input_path is None else input_path
        from amfe.io.bedfile import read_bed
        bed = on_root(mpi, read_bed, bed)
    source = material_source(bed, material)
    if isinstance(bed, Bed):
        centers, radii = bed.centers, bed.radii
        material = bed.material() if material is None else material
    elif isinstance(bed, (tuple, list)) and len(bed) == 2:
        centers, radii = bed
    else:
        raise AmfeError("homogenize: bed must be an amfe.Bed, a bed file's path, or "
                        f"(centers, radii); got {type(bed).__name__}")
    kw = {} if material is None else {"material": material}
    d = homogenize_bed(centers, radii, **kw, a_star_cap=a_star_cap,
                       rtol=DEFAULT_RTOL if rtol is None else rtol, max_it=max_it,
                       vtu_dir=vtu_dir, comm=pcomm, ksp_options=petsc_options, bc=bc,
                       diagnose=diagnose, progress=progress, fields=fields)
    describe_input(d, input_path, source)
    return Result.from_dict(d, fields=d.pop("fields", None))

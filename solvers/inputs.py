"""homogenize_bed's input, checked before any work: values, options, ranks and memory.

Everything that can be refused is refused here, before the frame is built
or PETSc assembles anything: the arrays (:func:`amfe.model.bonds.validate_particles`),
the material, the boundary condition (and the periodic box it may need),
rtol and -ksp_rtol (both in (0, 1)),
max_it, the a* cap's range, then that every rank holds the same of all of it
(max_memory included)
(:func:`amfe.solvers.consistency.agree_across_ranks`, one collective), then
the memory the solve would take against the limit summed over the machines
(:mod:`amfe.model.memory`).
"""
import math

import numpy as np

from amfe.errors import AmfeError
from amfe.model.bonds import check_a_star_cap, validate_particles
from amfe.model.material import STEEL, Material
from amfe.model.memory import check_memory, default_limit, solve_bytes
from amfe.model.torus import NOT_PERIODIC
from amfe.solvers.consistency import agree_across_ranks, digest


def check_rtol(value, name="rtol"):
    """``value`` as a float in (0, 1) (a relative tolerance), else AmfeError."""
    try:
        rtol = float(value)
    except (TypeError, ValueError):
        rtol = math.nan
    if isinstance(value, bool) or not 0.0 < rtol < 1.0:
        raise AmfeError(f"{name} must lie in (0, 1), got {value!r}")
    return rtol


def _check_options(PETSc, ksp_options, rtol, max_it):
    if rtol is not None:
        check_rtol(rtol)
    given = (ksp_options or {}).get("ksp_rtol", (ksp_options or {}).get("-ksp_rtol"))
    if given is None and PETSc.Options().hasName("ksp_rtol"):
        given = PETSc.Options().getString("ksp_rtol")
    if given is not None:
        check_rtol(given, "-ksp_rtol")
    if max_it is not None and (isinstance(max_it, bool)
                               or not isinstance(max_it, (int, np.integer)) or max_it < 1):
        raise AmfeError(f"max_it must be a positive integer, got {max_it!r}")


def checked_inputs(PETSc, mpi, centers, radii, material, *, bcs, bc, rtol, max_it, a_star_cap,
                   ksp_options, box=None, max_memory=None, input_error=None, **others):
    """(centers, radii, material, check) validated and the same on every rank of ``mpi``.

    bcs: the boundary conditions offered ({name: condition}, a condition's
    ``periodic`` saying it needs the periodic ``box``); ``others``: the remaining options
    that every rank must share (nondimensional, diagnose, ...). ``input_error``:
    an AmfeError the caller met preparing this rank's input, raised on every
    rank once the ranks are compared. check(estimate, what): raises the
    AmfeError of an estimate [bytes] over the memory limit (``max_memory``,
    default half the memory of the ranks' machines), for later estimates (a
    factorisation's). Collective on ``mpi``; raises the same error on every rank.
    """
    raw = {"centers": centers, "radii": radii}
    material = STEEL if material is None else material
    try:
        if input_error is not None:
            raise input_error
        if bc not in bcs:
            raise AmfeError(f"unknown boundary condition {bc!r}; choose one of " + ", ".join(bcs))
        if bcs[bc].periodic and box is None:
            raise AmfeError(NOT_PERIODIC)
        if not isinstance(material, Material):
            raise AmfeError(f"material must be an amfe.Material, got {type(material).__name__}")
        _check_options(PETSc, ksp_options, rtol, max_it)
        if a_star_cap is not None:
            check_a_star_cap(a_star_cap, material)
        centers, radii = validate_particles(centers, radii)
        error = None
    except AmfeError as exc:
        error = exc
    options = dict(bc=bc, rtol=rtol, max_it=max_it, a_star_cap=a_star_cap, box=digest(box),
                   max_memory=max_memory,   # refused below on one rank only: the same on all
                   ksp_options=sorted((ksp_options or {}).items()),
                   petsc=sorted(PETSc.Options().getAll().items()), **others)
    hosts = agree_across_ranks(mpi, {**raw, "material": repr(material),
                                     "options": repr(sorted(options.items()))}, error)
    default = sum(default_limit(memory) for memory in dict(hosts).values())

    def check(estimate, what):
        check_memory(estimate, max_memory, what, default=default)
    check(solve_bytes(radii.size, len(hosts)),
          f"homogenizing {radii.size} particles on {len(hosts)} rank(s)")
    return centers, radii, material, check

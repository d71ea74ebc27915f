"""homogenize_bed's input, checked before any work: values, options, ranks and memory.

Everything that can be refused is refused here, before the frame is built
or PETSc assembles anything: the arrays (:func:`amfe.model.bonds.validate_particles`),
the material, the boundary condition (and the periodic box it may need),
rtol and -ksp_rtol (both in (0, 1), and never both: :func:`check_no_override`),
max_it, the a* cap's range, then that every rank holds the same of all of it
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


def petsc_value(PETSc, ksp_options, name):
    """The value of PETSc option ``name`` for this solve: from ``ksp_options`` (with or without
    the dash), else the options database (the command line's); None when neither sets it."""
    options = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}
    if name in options:
        return options[name]
    return PETSc.Options().getString(name) if PETSc.Options().hasName(name) else None


# amfe's argument -> (the PETSc option that would silently override it: make_ksp sets the
# argument, then KSPSetFromOptions reads the option over it; where the argument is given;
# what it sets)
OVERRIDDEN_BY = {"rtol": ("ksp_rtol", "--rtol, or rtol= in Python", "tolerance"),
                 "max_it": ("ksp_max_it", "max_it= in Python", "iteration limit")}


def check_no_override(PETSc, ksp_options, **given):
    """AmfeError when an argument of ``given`` (rtol, max_it; None: not given) comes with the
    PETSc option that would replace it (-ksp_rtol, -ksp_max_it): one number, two sources.

    The PETSc option alone is honoured (and the rtol used is in the result's
    solver record); the argument alone too; both are refused, naming both.
    """
    for arg, value in given.items():
        option, where, what = OVERRIDDEN_BY[arg]
        theirs = petsc_value(PETSc, ksp_options, option)
        if value is not None and theirs is not None:
            raise AmfeError(f"{arg} {value:g} ({where}) and -{option} {theirs} both set the "
                            f"solves' {what}, and PETSc's would silently override amfe's: give "
                            "only one of them")


def _check_options(PETSc, ksp_options, rtol, max_it):
    if rtol is not None:
        check_rtol(rtol)
    given = petsc_value(PETSc, ksp_options, "ksp_rtol")
    if given is not None:
        check_rtol(given, "-ksp_rtol")
    if max_it is not None and (isinstance(max_it, bool)
                               or not isinstance(max_it, (int, np.integer)) or max_it < 1):
        raise AmfeError(f"max_it must be a positive integer, got {max_it!r}")
    check_no_override(PETSc, ksp_options, rtol=rtol, max_it=max_it)


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

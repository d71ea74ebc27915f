"""homogenize_bed's input, checked before any work: values, options, ranks and memory.

Everything that can be refused is refused here, before the frame is built
or PETSc assembles anything. The bed (:class:`amfe.model.bed.Bed`) and the
options (:class:`amfe.model.options.SolveOptions`) were checked when they were
made; here what needs both or PETSc: the periodic box the condition may need,
the material, -ksp_rtol in (0, 1) and never with rtol (:func:`check_no_override`),
the a* cap's range, then that every rank
holds the same of all of it (max_memory included)
(:func:`amfe.solvers.consistency.agree_across_ranks`, one collective), then
the memory the solve would take against the limit summed over the machines
(:mod:`amfe.model.memory`).
"""
from collections import namedtuple

from amfe.errors import AmfeError
from amfe.model.bed import Bed
from amfe.model.bonds import check_a_star_cap
from amfe.model.carrying import GivenBox
from amfe.model.material import resolve_material
from amfe.model.memory import check_memory, default_limit, solve_bytes
from amfe.model.options import SolveOptions, check_rtol
from amfe.model.torus import NOT_PERIODIC
from amfe.solvers.consistency import agree_across_ranks, digest
from amfe.solvers.petsclib import PETSc

#: What :func:`checked_inputs` hands on: the options, the material, its record for the
#: result ({E, nu, psi, source}), the periodic box (or None) and check_memory(estimate, what).
Inputs = namedtuple("Inputs", "options material record box check_memory")


def petsc_value(ksp_options, name):
    """The value of PETSc option ``name`` for this solve: from ``ksp_options`` (with or without
    the dash), else the options database (the command line's); None when neither sets it."""
    options = {k.lstrip("-"): v for k, v in (ksp_options or {}).items()}
    if name in options:
        return options[name]
    return PETSc.Options().getString(name) if PETSc.Options().hasName(name) else None


def given_options(names, ksp_options):
    """The options of ``names`` the caller set for this solve: in ``ksp_options`` (with or
    without the dash, as :func:`amfe.solvers.ksp.petsc_options` takes them) or in the
    options database (the command line's)."""
    keys = {k.lstrip("-") for k in ksp_options or {}}
    return [n for n in names if n in keys or PETSc.Options().hasName(n)]


# amfe's argument -> (the PETSc option that would silently override it: make_ksp sets the
# argument, then KSPSetFromOptions reads the option over it; where the argument is given;
# what it sets)
OVERRIDDEN_BY = {"rtol": ("ksp_rtol", "--rtol, or rtol= in Python", "tolerance"),
                 "max_it": ("ksp_max_it", "max_it= in Python", "iteration limit")}


def check_no_override(ksp_options, **given):
    """AmfeError when an argument of ``given`` (rtol, max_it; None: not given) comes with the
    PETSc option that would replace it (-ksp_rtol, -ksp_max_it): one number, two sources.

    The PETSc option alone is honoured (and the rtol used is in the result's
    solver record); the argument alone too; both are refused, naming both.
    """
    for arg, value in given.items():
        option, where, what = OVERRIDDEN_BY[arg]
        theirs = petsc_value(ksp_options, option)
        if value is not None and theirs is not None:
            raise AmfeError(f"{arg} {value:g} ({where}) and -{option} {theirs} both set the "
                            f"solves' {what}, and PETSc's would silently override amfe's: give "
                            "only one of them")


def _check_options(options):
    given = petsc_value(options.ksp_options, "ksp_rtol")
    if given is not None:
        check_rtol(given, "-ksp_rtol")
    check_no_override(options.ksp_options, rtol=options.rtol, max_it=options.max_it)


def _material(bed, options):
    """(Material, its record {E, nu, psi, source}): the options' material, else the bed's."""
    if options.material is None:
        material, record = resolve_material(bed.attrs, None)
        return material, {**record, "source": options.material_source or record["source"]}
    material = options.material
    return material, {"E": material.E, "nu": material.nu, "psi": material.psi,
                      "source": options.material_source or "argument"}


def checked_inputs(mpi, bed, options, bcs, input_error=None):
    """:data:`Inputs` of a solve, checked and the same on every rank of ``mpi``.

    bed: a :class:`~amfe.model.bed.Bed` (its arrays were checked when it was
    made); options: a :class:`~amfe.model.options.SolveOptions` (its values were
    checked when it was made; here what needs the bed or PETSc: the condition's
    periodic box, the a* cap against the material, -ksp_rtol); bcs: the
    boundary conditions offered ({name: condition}, a condition's ``periodic``
    saying it needs the periodic box). ``input_error``: an AmfeError the caller
    met preparing this rank's input, raised on every rank once the ranks are
    compared. check_memory(estimate, what): raises the AmfeError of an estimate
    [bytes] over the memory limit (``max_memory``, default half the memory of
    the ranks' machines), for later estimates (a factorisation's). Collective
    on ``mpi``; raises the same error on every rank.
    """
    material = record = box = None
    try:
        if input_error is not None:
            raise input_error
        if not isinstance(bed, Bed):
            raise AmfeError(f"bed must be an amfe.Bed, got {type(bed).__name__}")
        if not isinstance(options, SolveOptions):
            raise AmfeError(f"options must be an amfe.model.options.SolveOptions, got "
                            f"{type(options).__name__}")
        box = bed.attrs.get("periodic")
        if bcs[options.bc].periodic and box is None:
            raise AmfeError(NOT_PERIODIC)
        if options.box is not None and bcs[options.bc].periodic:
            raise AmfeError(f"--box sets V's box, but under {options.bc} V is the periodic "
                            "bed's box, its periods: leave --box out")
        material, record = _material(bed, options)
        _check_options(options)
        if options.a_star_cap is not None:
            check_a_star_cap(options.a_star_cap, material)
        error = None
    except AmfeError as exc:
        error = exc
    given = None
    if isinstance(options, SolveOptions):
        given = dict(sorted(vars(options).items()), material=repr(options.material),
                     ksp_options=sorted(options.ksp_options.items()), box=digest(box))
    hosts = agree_across_ranks(mpi, {**_arrays(bed), "material": repr(material),
                                     "options": repr(given),
                                     "petsc": repr(sorted(PETSc.Options().getAll().items()))},
                               error)
    default = sum(default_limit(memory) for memory in dict(hosts).values())

    def check(estimate, what):
        check_memory(estimate, options.max_memory, what, default=default)
    check(solve_bytes(bed.radii.size, len(hosts)),
          f"homogenizing {bed.radii.size} particles on {len(hosts)} rank(s)")
    return Inputs(options, material, record, box, check)


def given_size(bed, options):
    """The ``size`` of V's box rule (:func:`amfe.model.carrying.box_rule`): the options' given
    box (a GivenBox), else the bed's recorded size (attrs ``size``), else None."""
    if options.box is not None:
        return GivenBox(options.box)
    return bed.attrs.get("size")


def _arrays(bed):
    """{"centers", "radii"} of a Bed, or of the (centers, radii) a rank could not make one of
    (compared across the ranks all the same, to say which differ)."""
    if isinstance(bed, Bed):
        return {"centers": bed.centers, "radii": bed.radii}
    if isinstance(bed, (tuple, list)) and len(bed) == 2:
        return {"centers": bed[0], "radii": bed[1]}
    return {"centers": None, "radii": None}

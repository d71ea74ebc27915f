"""PETSc start-up: initialise petsc4py once, with command-line options if given."""
import sys

_initialised = False


def init_petsc(argv=None):
    """Initialise petsc4py (once) and return the PETSc module.

    ``argv``: PETSc options such as ["-ksp_monitor", "-log_view"]; they must
    reach PetscInitialize for -log_view and friends to work, so pass them on
    the first call. Later calls add them to the options database instead.
    """
    global _initialised
    import petsc4py
    if not _initialised and "petsc4py.PETSc" not in sys.modules:
        petsc4py.init([sys.argv[0] if sys.argv else "amfe"] + list(argv or []))
    _initialised = True
    from petsc4py import PETSc
    if argv and not _initialised_with(argv):
        opts = PETSc.Options()
        for name, value in _pairs(argv):
            opts.setValue(name, value)
    return PETSc


def _initialised_with(argv):
    from petsc4py import PETSc
    opts = PETSc.Options()
    return all(opts.hasName(name) for name, _ in _pairs(argv))


def _pairs(argv):
    """[("-ksp_type", "cg"), ("-ksp_monitor", "")] from a flat option list."""
    out, k = [], 0
    while k < len(argv):
        name = argv[k].lstrip("-")
        value = ""
        if k + 1 < len(argv) and not _is_option(argv[k + 1]):
            value = argv[k + 1]
            k += 1
        out.append((name, value))
        k += 1
    return out


def _is_option(token):
    if not token.startswith("-"):
        return False
    try:
        float(token)
        return False  # a negative number is a value
    except ValueError:
        return True

"""PETSc start-up: initialise petsc4py once, with command-line options if given."""
import sys


def init_petsc(argv=None):
    """Initialise petsc4py if needed and return the PETSc module.

    ``argv``: PETSc options such as ["-ksp_monitor", "-log_view"]. On the first
    call they go to PetscInitialize (which -log_view needs); if PETSc is already
    initialised they are added to its options database instead.
    """
    argv = list(argv or [])
    if "petsc4py.PETSc" not in sys.modules:
        import petsc4py
        petsc4py.init([sys.argv[0] if sys.argv and sys.argv[0] else "amfe"] + argv)
        _keep_python_sigpipe()
        from petsc4py import PETSc
        return PETSc
    from petsc4py import PETSc
    opts = PETSc.Options()
    for name, value in option_pairs(argv):
        opts.setValue(name, value)
    return PETSc


def _keep_python_sigpipe():
    """Undo PETSc's SIGPIPE handler: it turns a closed stdout pipe (`amfe ... | head`) into a
    PETSc error and MPI_Abort. With Python's SIG_IGN the write raises BrokenPipeError, which
    the command line ends quietly (amfe.cli.interrupt)."""
    import signal
    try:
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    except ValueError:   # not the main thread: leave it
        pass


def option_pairs(argv):
    """[("ksp_type", "cg"), ("ksp_monitor", "")] from ["-ksp_type", "cg", "-ksp_monitor"]."""
    out, k = [], 0
    while k < len(argv):
        name, value = argv[k].lstrip("-"), ""
        if k + 1 < len(argv) and not is_option(argv[k + 1]):
            value = argv[k + 1]
            k += 1
        out.append((name, value))
        k += 1
    return out


def is_option(token):
    """True for -name, False for a value such as 'cg', '1e-3' or '-2'."""
    if not token.startswith("-"):
        return False
    try:
        float(token)
        return False
    except ValueError:
        return True

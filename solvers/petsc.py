"""PETSc start-up: initialise petsc4py once, with command-line options if given."""
import ctypes
import logging
import os
import signal
import sys

from amfe.errors import AmfeError


def init_petsc(argv=None):
    """Initialise petsc4py if needed and return the PETSc module.

    ``argv``: the command line's PETSc options, such as ["-ksp_monitor",
    "-log_view"]. On the first call they go to PetscInitialize (which -log_view
    needs); if PETSc is already initialised they are added to its options
    database instead (in place of an earlier command line's). Either way they
    are recorded as the command line's (:func:`command_line_pairs`): every
    solve of this process applies them (:mod:`amfe.solvers.options`). None (or
    no argument): initialise if needed, change nothing.
    """
    if argv is not None:
        argv = list(argv)
        check_startup_options(argv)
    if "petsc4py.PETSc" not in sys.modules:
        import petsc4py  # noqa: PLC0415 (heavy or optional: loaded when used)
        # the program's name first; under `python -c` sys.argv[0] is "-c", which
        # PETSc would take for an option ("PETSc options never used: -c")
        prog = sys.argv[0] if sys.argv and sys.argv[0] and not sys.argv[0].startswith("-") \
            else "amfe"
        try:
            petsc4py.init([prog] + (argv or []))
        except Exception as exc:   # petsc4py.PETSc.Error: PetscInitialize failed (every rank)
            raise AmfeError(f"PETSc could not start with the options {' '.join(argv or [])} "
                            f"({exc}); check them against the PETSc manual") from None
        _keep_python_signals()
        _command_line[:] = option_pairs(argv or [])
        from petsc4py import PETSc  # noqa: PLC0415 (heavy or optional: loaded when used)
        return PETSc
    from petsc4py import PETSc  # noqa: PLC0415 (heavy or optional: loaded when used)
    if argv is not None:
        opts = PETSc.Options()
        pairs = option_pairs(argv)
        for name, _ in _command_line:
            if name not in dict(pairs) and opts.hasName(name):
                opts.delValue(name)
        for name, value in pairs:
            opts.setValue(name, value)
        _command_line[:] = pairs
    return PETSc


_command_line = []   # [(name, value)]: the command line's PETSc options (init_petsc)


def command_line_pairs():
    """[(name, value)] of the PETSc options of the command line (:func:`init_petsc`)."""
    return list(_command_line)


#: Option names (without the dash) that set up PETSc objects or amfe's solves: one call's.
OBJECT_PREFIXES = ("ksp_", "pc_", "mg_", "mat", "vec_", "sub_", "redundant_", "fieldsplit_",
                   "amfe_", "snes_", "ts_", "tao_", "dm_", "is_", "sf_", "gamg_", "esteig_")


def is_object_option(name):
    """True for an option of a solver object (``ksp_rtol``, ``-pc_type``), False for a
    process-wide one (``log_view``, ``info``, ``malloc_debug``, ``help``)."""
    return name.lstrip("-").startswith(OBJECT_PREFIXES)


def forget_command_line():
    """The end of a command (amfe.cli): its solver options out of the database and the record
    (a later call in this process, a test's, is not that command's); process-wide ones such as
    -log_view stay for PetscFinalize."""
    if "petsc4py.PETSc" in sys.modules:
        from petsc4py import PETSc  # noqa: PLC0415 (heavy or optional: loaded when used)
        opts = PETSc.Options()
        for name, _ in _command_line:
            if is_object_option(name) and opts.hasName(name):
                opts.delValue(name)
    _command_line[:] = []


# Options amfe refuses before PETSc starts, with why.
REFUSED_OPTIONS = {
    "fp_trap": "it makes every floating-point exception fatal, and amfe's numpy code relies on "
               "IEEE infinities and NaN where they are checked (PETSc would abort the run with "
               "its error banner); -fp_trap is for debugging PETSc itself",
}


def check_startup_options(argv):
    """AmfeError for a PETSc option amfe cannot run with (:data:`REFUSED_OPTIONS`) or an
    ``-options_file`` that cannot be read (PetscInitialize would fail with error 83 and a
    traceback). argv: the PETSc options, as for :func:`init_petsc`."""
    for name, value in option_pairs(argv):
        if name in REFUSED_OPTIONS and value.lower() not in ("0", "false", "no", "off"):
            raise AmfeError(f"-{name} is not supported: {REFUSED_OPTIONS[name]}")
        if name in ("options_file", "options_file_yaml"):
            if not value:
                raise AmfeError(f"-{name} needs a file name")
            if not os.path.isfile(value) or not os.access(value, os.R_OK):
                why = ("does not exist" if not os.path.exists(value) else
                       "is a directory" if os.path.isdir(value) else "cannot be read")
                raise AmfeError(f"-{name} {value}: the file {why}")


def _keep_python_signals():
    """Undo PETSc's handlers of the signals Python handles.

    SIGPIPE: PETSc turns a closed stdout pipe (`amfe ... | head`) into a PETSc
    error and MPI_Abort; with Python's SIG_IGN the write raises BrokenPipeError,
    which the command line ends quietly. SIGHUP, SIGQUIT (and SIGINT, SIGTERM):
    PETSc prints "Caught signal" and calls MPI_Abort with its banner; the
    command line's handlers end the run with one line (amfe.cli.interrupt),
    and elsewhere the signal does what it did before PETSc started.
    """
    for sig in (signal.SIGPIPE, signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT):
        handler = signal.getsignal(sig)   # Python's own record, which PETSc did not change
        if handler is None:   # set outside Python: leave it
            continue
        try:
            signal.signal(sig, handler)
        except ValueError:   # not the main thread: leave it
            return


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


# Options PETSc reads only in PetscFinalize (or never, for -help): not "unused" before then.
READ_AT_FINALIZE = frozenset({"options_left", "options_view", "memory_view_threshold", "help"})
_warned = set()
_used_fn = {}  # "fn": PetscOptionsUsed, looked up once


def _options_used_fn():
    """PetscOptionsUsed from the PETSc library petsc4py loaded (None if not found).

    petsc4py 3.18 has no binding for it; the library is the one mapped into
    this process (so the same options database), found in /proc/self/maps.
    """
    path = None
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                name = line.split()[-1]
                if "/libpetsc" in name and ".so" in name:
                    path = name
                    break
        fn = ctypes.CDLL(path).PetscOptionsUsed if path else None
    except (OSError, AttributeError):
        return None
    if fn is not None:
        fn.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_int)]
        fn.restype = ctypes.c_int
    return fn


def option_used(name):
    """True if PETSc has read option ``name`` (without the dash); None if that cannot be told."""
    if "fn" not in _used_fn:
        _used_fn["fn"] = _options_used_fn()
    fn = _used_fn["fn"]
    flag = ctypes.c_int(0)
    if fn is None or fn(None, name.encode(), ctypes.byref(flag)) != 0:
        return None
    return bool(flag.value)


def unused_options(names=None):
    """The options of the database (or of ``names``) that PETSc never read, as "-name".

    Call it after the solves: an option read only by an object never
    created (-pc_hypre_* with GAMG) or misspelt (-ksp_rtoll) is unused.
    Options read only at PetscFinalize (-options_left) are left out.
    """
    PETSc = init_petsc()   # this module initialises PETSc: it does not import it at the top
    names = list(PETSc.Options().getAll()) if names is None else list(names)
    return [f"-{n}" for n in names
            if n.lstrip("-") not in READ_AT_FINALIZE and option_used(n.lstrip("-")) is False]


def unused_options_warning(rank, extra=(), names=None):
    """One line naming the options never used (of ``names``, "-name", else of the whole
    database; with ``extra``, names already found unused elsewhere), or None. Rank 0 logs it
    as a warning (logger "amfe.solvers") the first time these names come up in this process
    (a data set's hundred solves warn once); every rank returns it for the JSON.
    """
    names = sorted(set(unused_options() if names is None else names) | set(extra))
    if not names:
        return None
    line = (f"PETSc options never used: {' '.join(names)} (misspelt, or meant for a solver "
            "or preconditioner that was not used); they had no effect")
    if rank == 0 and not set(names) <= _warned:
        logging.getLogger("amfe.solvers").warning(line)
    _warned.update(names)
    return line

"""How a run ends early: on SIGINT, SIGTERM, SIGHUP or SIGQUIT, on a closed pipe, with every rank.

From the start of :func:`amfe.cli.main` (the subcommands' imports included),
SIGINT, SIGTERM, SIGHUP and SIGQUIT raise :class:`Interrupted` in the main
thread (Python runs signal handlers between bytecodes, so a rank inside a C
call such as one PETSc solve handles it when that call returns; PETSc's own
handlers of SIGHUP and SIGQUIT, with their "Caught signal" and MPI_ABORT
banners, are undone when it starts, amfe.solvers.petsc). The
exception unwinds the Python stack: ``amfe.io.atomic`` removes the temporary
file of a write in progress, finished files stay. :func:`end_interrupted`
then prints one line, ``amfe <command>: interrupted (SIGINT)``, and the run
exits with 128 + the signal number (130, 143, 129, 131), as a shell reports a
program killed by that signal.

Under mpirun a signal may reach one rank only (``kill -INT <pid of rank 0>``)
and the others would wait in their next collective for ever. So a rank that
was interrupted while MPI runs on more than one rank calls ``MPI_Abort`` with
that exit code after printing: Open MPI then ends every rank (SIGTERM, and
SIGKILL one second later, ``odls_base_sigkill_timeout``), prints its own
"MPI_ABORT was invoked" banner, and mpirun exits with the code. Rank 0 speaks
at once; another rank first waits :data:`NONROOT_GRACE` seconds, longer than
that SIGKILL delay, so that when the signal reached rank 0 too (or came from
Open MPI ending the job) rank 0's line is the only one. A signal before MPI
started, or inside MPI_Init, leaves no communicator to abort: the rank then
leaves with os._exit (a normal exit would wait in MPI_Finalize for the other
ranks) and mpirun ends the job, with its own banner.

A reader that closes the pipe early (``amfe dataset --check x.h5 | head``)
makes the next write raise BrokenPipeError: :func:`end_broken_pipe` points
stdout at /dev/null so the interpreter's final flush stays quiet (the
recipe of the Python docs, "Note on SIGPIPE") and the run exits with 141 =
128 + SIGPIPE, what a shell tool killed by SIGPIPE reports.
"""
import contextlib
import os
import signal
import sys
import threading
import time

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
NONROOT_GRACE = 2.0   # s; > Open MPI's 1 s from SIGTERM to SIGKILL when it ends a job
BROKEN_PIPE_EXIT = 128 + signal.SIGPIPE


class Interrupted(BaseException):
    """One of :data:`SIGNALS` arrived while a subcommand ran (a BaseException, like Ctrl-C's,
    so that no ``except Exception`` swallows it)."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def exit_code(self):
        return 128 + self.signum


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def _ignore(signum, frame):
    """A second signal while the first one is being handled: the run is ending already."""


@contextlib.contextmanager
def signals_raise():
    """Within the block, :data:`SIGNALS` raise :class:`Interrupted`; the old handlers after.

    Only the main thread may set handlers: elsewhere (amfe.cli.main called
    from a worker thread) the block runs with the handlers as they are.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_interrupted) for s in SIGNALS}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def world():
    """MPI_COMM_WORLD when this process runs MPI on more than one rank, else None.

    Never imports mpi4py: a command that did not start MPI has no other rank
    to stop.
    """
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is None or not mpi.Is_initialized() or mpi.Is_finalized():
        return None
    return mpi.COMM_WORLD if mpi.COMM_WORLD.size > 1 else None


def end_interrupted(command, exc):
    """Print the one line of an interrupted run and stop every rank; returns the exit code.

    command: the subcommand's name, or "" when the signal came before it was known."""
    if threading.current_thread() is threading.main_thread():
        for s in SIGNALS:   # Open MPI's SIGTERM to this rank must not restart the ending
            signal.signal(s, _ignore)
    comm = world()
    # Under mpirun but without a usable MPI_COMM_WORLD: the signal came before MPI started,
    # or inside `from mpi4py import MPI` (MPI_Init done, the module never registered). A normal
    # exit would then wait in mpi4py's MPI_Finalize for ranks that wait in a collective: leave
    # at once instead (os._exit); mpirun sees a rank end without finalising and ends the job.
    half_started = comm is None and launcher_size() > 1
    rank = comm.rank if comm is not None else launcher_rank()
    if rank != 0 and (comm is not None or half_started):
        time.sleep(NONROOT_GRACE)
    _say(f"amfe{' ' + command if command else ''}: interrupted "
         f"({signal.Signals(exc.signum).name})")
    if comm is not None:
        comm.Abort(exc.exit_code)
    if half_started:
        flush_stdout()
        os._exit(exc.exit_code)
    return exc.exit_code


def _launcher_env(names):
    for var in names:
        value = os.environ.get(var, "")
        if value.isdigit():
            return int(value)
    return None


def launcher_rank():
    """This process's rank under mpirun, from the launcher's environment (0 alone); no MPI
    needed (argparse errors and early signals come before MPI starts)."""
    return _launcher_env(("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK")) or 0


def launcher_size():
    """The number of ranks mpirun started (1 alone), from the launcher's environment."""
    return _launcher_env(("OMPI_COMM_WORLD_SIZE", "PMI_SIZE")) or 1


def end_broken_pipe():
    """Silence stdout after the reader went away; returns the exit code (141)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):   # stdout replaced (tests) or closed
        pass
    return BROKEN_PIPE_EXIT


def flush_stdout():
    """Flush stdout now; False when the reader has closed the pipe (BrokenPipeError)."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        return False
    except (OSError, ValueError, AttributeError):   # closed or replaced: nothing to flush
        pass
    return True


def _say(line):
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):   # stderr gone too: the exit code still says it
        pass

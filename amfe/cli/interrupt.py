"""How a run ends early: on SIGINT or SIGTERM, on a closed pipe, with every MPI rank.

While a subcommand runs, SIGINT and SIGTERM raise :class:`Interrupted` in the
main thread (Python runs signal handlers between bytecodes, so a rank inside
a C call such as one PETSc solve handles it when that call returns). The
exception unwinds the Python stack: ``amfe.io.atomic`` removes the temporary
file of a write in progress, finished files stay. :func:`end_interrupted`
then prints one line, ``amfe <command>: interrupted (SIGINT)``, and the run
exits with 128 + the signal number (130, 143), as a shell reports a program
killed by that signal.

Under mpirun a signal may reach one rank only (``kill -INT <pid of rank 0>``)
and the others would wait in their next collective for ever. So a rank that
was interrupted while MPI runs on more than one rank calls ``MPI_Abort`` with
that exit code after printing: Open MPI then ends every rank (SIGTERM, and
SIGKILL one second later, ``odls_base_sigkill_timeout``), prints its own
"MPI_ABORT was invoked" banner, and mpirun exits with the code. Rank 0 speaks
at once; another rank first waits :data:`NONROOT_GRACE` seconds, longer than
that SIGKILL delay, so that when the signal reached rank 0 too (or came from
Open MPI ending the job) rank 0's line is the only one.

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

SIGNALS = (signal.SIGINT, signal.SIGTERM)
NONROOT_GRACE = 2.0   # s; > Open MPI's 1 s from SIGTERM to SIGKILL when it ends a job
BROKEN_PIPE_EXIT = 128 + signal.SIGPIPE


class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived while a subcommand ran (a BaseException, like KeyboardInterrupt,
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
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted`; the old handlers after.

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
    """Print the one line of an interrupted run and stop every rank; returns the exit code."""
    if threading.current_thread() is threading.main_thread():
        for s in SIGNALS:   # Open MPI's SIGTERM to this rank must not restart the ending
            signal.signal(s, _ignore)
    comm = world()
    if comm is not None and comm.rank != 0:
        time.sleep(NONROOT_GRACE)
    _say(f"amfe {command}: interrupted ({signal.Signals(exc.signum).name})")
    if comm is not None:
        comm.Abort(exc.exit_code)
    return exc.exit_code


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

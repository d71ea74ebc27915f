"""Blocks that a signal must not cut in the middle: third-party C code that an exception
raised halfway leaves broken.

scipy's qhull wrapper (ConvexHull) segfaults when a Python signal handler raises while it
builds its message stream (scipy issue 19383): the half-made object's clean-up frees what
was never allocated, at garbage collection or interpreter exit. A Ctrl-C or a SIGTERM to
``amfe dataset`` at that moment ended the run with PETSc's SEGV banner and exit 59 instead
of one line and 143 (amfe.cli.interrupt). Inside :func:`signals_deferred` such a signal is
only recorded; when the block ends, the handler that was in place runs with it, as if the
signal had arrived just then.
"""
import contextlib
import signal
import threading

DEFERRED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


@contextlib.contextmanager
def signals_deferred():
    """Hold SIGINT, SIGTERM, SIGHUP and SIGQUIT until the block ends, then deliver the first.

    Only the main thread may set handlers (and Python runs them only there): elsewhere the
    block runs as it is. Handlers set outside Python (``signal.getsignal`` None) are left.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    old = {}
    for sig in DEFERRED:
        handler = signal.getsignal(sig)
        if handler is not None and handler is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, lambda signum, frame: caught.append((signum, frame)))
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        if caught:
            signum, frame = caught[0]
            handler = old[signum]
            if callable(handler):
                handler(signum, frame)
            else:   # SIG_DFL: the default action, now that the block is done
                signal.raise_signal(signum)

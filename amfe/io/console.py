"""What the solver layer reports, printed: its ``logging`` records on stderr.

The solver layer prints nothing (:mod:`amfe.solvers` logs progress at INFO and
warnings at WARNING to the logger ``amfe.solvers``, on rank 0 only); the face
decides what reaches the terminal. :func:`messages` prints the warnings as
"amfe: warning: ..." and, with ``progress``, the progress lines with the
seconds since it began, on stderr, for as long as it is entered.
"""
import logging
import sys
import time
from contextlib import contextmanager

LOGGER = "amfe.solvers"


class Console(logging.Handler):
    """Prints the warnings (``progress=False``) or the progress lines of the solver layer."""

    def __init__(self, progress=False):
        super().__init__(logging.INFO if progress else logging.WARNING)
        self.progress = progress
        self.start = time.perf_counter()

    def emit(self, record):
        if (record.levelno < logging.WARNING) != self.progress:
            return
        text = record.getMessage()
        line = (f"[{time.perf_counter() - self.start:7.2f} s] {text}" if self.progress
                else f"amfe: warning: {text}")
        try:
            print(line, file=sys.stderr, flush=True)
        except OSError:
            # stderr is gone (the mpirun or terminal that read it was killed): a message that
            # cannot be shown must not fail the work, which a data set would record as a
            # failed bed and keep on resume.
            pass


def print_warnings():
    """Print the solver layer's warnings on stderr from now on (once per process)."""
    logger = logging.getLogger(LOGGER)
    if not any(isinstance(h, Console) and not h.progress for h in logger.handlers):
        logger.addHandler(Console())


@contextmanager
def messages(progress=False):
    """Inside: the solver layer's warnings (and with ``progress`` its progress lines) on stderr."""
    print_warnings()
    logger = logging.getLogger(LOGGER)
    if not progress:
        yield
        return
    handler, level = Console(progress=True), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)

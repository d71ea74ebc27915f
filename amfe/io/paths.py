"""Output paths checked before any work: a bad ``-o`` costs nothing and destroys nothing.

Every command checks each output it will write before it reads, solves or
trains (:func:`check_output`, :func:`check_output_dir`): the directory must
exist and take a new file (tried for real, which also catches /proc and
read-only mounts), the path must not be a directory, and it must not be one
of the command's inputs (``amfe homogenize bed.h5 -o bed.h5`` would otherwise
replace the bed by its result). A FIFO or a character device is accepted when
writable (it is written through, amfe.io.atomic), a block device or a socket refused.
"""
import os
import tempfile

from amfe.errors import AmfeError
from amfe.io.atomic import WRITTEN_THROUGH, own_stream, refuse_special

STDOUT = "-"


def _same_file(a, b):
    """True when a and b name one file (hard and symbolic links included)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist yet
        return False


def _probe_directory(directory, what):
    """Create and remove a temporary file in ``directory``; AmfeError if that fails."""
    if not os.path.exists(directory):
        raise AmfeError(f"cannot write {what}: the directory {directory} does not exist")
    if not os.path.isdir(directory):
        raise AmfeError(f"cannot write {what}: {directory} is not a directory")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".amfe-probe-", dir=directory)
    except OSError as exc:
        raise AmfeError(f"cannot write {what} in {directory}: {exc.strerror or exc}") from None
    os.close(fd)
    os.remove(tmp)


def check_output(path, *, inputs=(), option="-o", allow_stdout=False):
    """Refuse an output file path that cannot be written or that names an input.

    path: str or path-like (``"-"``: standard output, when ``allow_stdout``);
    inputs: the paths the command reads. Returns ``path`` as a str. Raises
    AmfeError with the option's name and the fix.
    """
    path = os.fspath(path)
    if path == STDOUT and allow_stdout:
        return path
    what = f"{option} {path}"
    if path == "" or path.endswith(os.sep):
        raise AmfeError(f"{option} needs a file name, got {path!r}")
    if os.path.isdir(path):
        raise AmfeError(f"cannot write {what}: it is a directory; give a file name "
                        f"(e.g. {os.path.join(path, 'result.json')})")
    for inp in inputs:
        if inp is not None and _same_file(path, os.fspath(inp)):
            raise AmfeError(f"{option} {path} is also an input of this command: writing it "
                            "would destroy the input; choose another output file")
    if refuse_special(path, what) in WRITTEN_THROUGH:   # written through, not replaced: no probe
        if not os.access(path, os.W_OK):
            raise AmfeError(f"cannot write {what}: permission denied")
        return path
    # a symbolic link's target is what gets replaced
    _probe_directory(os.path.dirname(os.path.realpath(path)), what)
    return path


def is_stdout(path):
    """True when the output ``path`` is standard output: ``-``, or /dev/stdout and its kin
    (this process's stdout, reached by a link)."""
    path = os.fspath(path)
    return path == STDOUT or (os.path.islink(path) and own_stream(path) == 1)


def check_output_dir(path, *, option="--vtu"):
    """Refuse an output directory that cannot be made or written. Returns ``path`` as a str.

    An existing directory must take a new file; a missing one must have a
    writable parent (it is created when the files are written).
    """
    path = os.fspath(path)
    what = f"{option} {path}"
    if path == "":
        raise AmfeError(f"{option} needs a directory name, got ''")
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise AmfeError(f"cannot write {what}: it exists and is not a directory")
        _probe_directory(path, what)
        return path
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):  # created with parents when written
        parent = os.path.dirname(parent)
    _probe_directory(parent, what)
    return path

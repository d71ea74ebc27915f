"""Atomic file writes: a reader, a crash or a kill never sees half a file.

Every file amfe writes goes through a temporary file in the target's
directory, is flushed and fsynced, and is renamed onto its final name with
os.replace; the directory is fsynced so the rename survives a power cut.

The temporary file is ``.NAME.HOST-PID.XXXXXXXX.tmp`` (HOST: this machine's
name, letters, digits and dashes only; PID: the writing process). A kill
between the write and the rename leaves it behind; the next write of the same
``NAME`` removes it when it is certainly orphaned (:func:`stale_tmp_files`).
A full disk (ENOSPC) or an exhausted quota (EDQUOT) becomes one AmfeError
line, "no space left on DIR: ...", with the old file kept. HDF5 files are
best written with :func:`atomic_write_h5` (built in memory): the HDF5 library
handles a full disk badly (a segmentation fault at exit).

Only a regular file (or a new name) is replaced. A symbolic link is kept and
its target written (atomically, if a regular file). A FIFO or a character
device (/dev/null, a terminal, /dev/stdout) is written through, as ``cat >``
would, never replaced: the whole content is made in a temporary file first,
then copied to it (to this process's own stdout or stderr on their file
descriptors, so that ``-o /dev/stdout >> log`` appends). Block devices and
sockets are refused (:func:`file_kind`).
"""
import errno
import json
import os
import re
import shutil
import socket
import stat
import sys
import tempfile
import time

from amfe.errors import AmfeError

#: An orphaned temporary file of another host, or of a name without a pid
#: (written before the pid was part of the name), is removed once its last
#: change is older than this [s]: a live writer changes its file continually,
#: and writes a part file or a JSON result in well under a second.
STALE_AGE_UNKNOWN_WRITER = 60.0
#: A temporary file whose pid is running on this host is kept unless it is
#: older than this [s] (the pid has been reused, e.g. after a reboot).
STALE_AGE_LIVE_PID = 24 * 3600.0
_NO_SPACE = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}
_RANDOM = r"[a-z0-9_]{8}"   # tempfile's random part


def host_name():
    """This machine's name with only letters, digits and dashes (the tmp-name field)."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname()) or "host"


def pid_running(pid):
    """True if a process ``pid`` runs on this host (a zombie counts as ended)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError):
        return False
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def is_no_space(exc):
    """True for an error that means the disk or the quota is full (h5py's included)."""
    if isinstance(exc, OSError) and exc.errno in _NO_SPACE:
        return True
    text = str(exc)
    return any(f"errno = {e}," in text or os.strerror(e) in text for e in _NO_SPACE)


class NoSpaceError(AmfeError):
    """A file could not be written: the disk or the quota is full. ``path``: that file."""

    def __init__(self, message, path):
        super().__init__(message)
        self.path = path

    def __reduce__(self):   # picklable with its path (MPI broadcasts errors)
        return (type(self), (str(self), self.path))


def no_space_error(path, existed):
    """The one-line NoSpaceError for a full disk while writing ``path``."""
    directory = os.path.dirname(os.path.abspath(path))
    kept = "the old file is kept" if existed else "nothing was written"
    return NoSpaceError(f"no space left on {directory}: {os.path.basename(path)} could not be "
                        f"written ({kept}); free some space and run the command again", path)


def stale_tmp_files(path, every_target=False, now=None):
    """[(tmp path, why)] of the orphaned temporary files of target ``path``.

    Only ``.NAME.*.tmp`` files of this very NAME are considered (with
    ``every_target``, ``path`` is a directory and every NAME in it). One is
    stale when its name carries this host and a pid that no longer runs
    (whatever its age), when that pid runs but the file is older than
    STALE_AGE_LIVE_PID, or, for another host's file or a name without a pid,
    when it is older than STALE_AGE_UNKNOWN_WRITER.
    """
    path = os.fspath(path)
    if every_target:
        directory, name = path, ".+?"
    else:
        directory, name = os.path.dirname(os.path.abspath(path)), re.escape(os.path.basename(path))
    pattern = re.compile(r"^\." + name + r"\.(?:(?P<host>[A-Za-z0-9-]*)-(?P<pid>\d+)\.)?"
                         + _RANDOM + r"\.tmp$")
    try:
        names = [n for n in os.listdir(directory) if n.startswith(".") and n.endswith(".tmp")]
    except OSError:
        return []
    now = time.time() if now is None else now
    out = []
    for name in names:
        m = pattern.match(name)
        if m:
            tmp = os.path.join(directory, name)
            why = _stale_why(tmp, m.group("host"), m.group("pid"), now)
            if why:
                out.append((tmp, why))
    return out


def _stale_why(tmp, host, pid, now):
    """Why the temporary file ``tmp`` of writer (host, pid) is orphaned, or None."""
    try:
        age = now - os.stat(tmp).st_mtime
    except OSError:
        return None
    pid = int(pid) if pid else None
    if pid is not None and host == host_name():
        if pid == os.getpid():
            return None
        if not pid_running(pid):
            return f"its writer, pid {pid} on this host, has ended"
        if age > STALE_AGE_LIVE_PID:
            return f"unchanged for {age:.0f} s (pid {pid} is another process now)"
        return None
    if age > STALE_AGE_UNKNOWN_WRITER:
        writer = f"pid {pid} on host {host}" if pid is not None else "unknown"
        return f"unchanged for {age:.0f} s, writer {writer}"
    return None


def remove_stale_tmp(path, report=None, every_target=False):
    """Remove the orphaned temporary files of target ``path``; one line each on ``report``.

    report: a text stream (default sys.stderr) or False for silence;
    every_target: see :func:`stale_tmp_files`. Returns the list of (tmp path,
    why) removed.
    """
    removed = []
    for tmp, why in stale_tmp_files(path, every_target):
        try:
            os.remove(tmp)
        except OSError:
            continue
        removed.append((tmp, why))
        if report is not False:
            try:   # best effort: a closed stderr must not stop the write
                print(f"amfe: removed the stale temporary file {tmp} ({why})",
                      file=sys.stderr if report is None else report)
            except (OSError, ValueError):
                pass
    return removed


WRITTEN_THROUGH = ("fifo", "character device")
REFUSED = ("block device", "socket", "directory", "special file", "loop of symbolic links")


def file_kind(path):
    """What ``path`` names once symbolic links are followed: "missing", "regular", "fifo",
    "character device", "block device", "socket", "directory", "special file" or "loop of
    symbolic links"."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return "missing"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "loop of symbolic links"
        raise
    for test, kind in ((stat.S_ISREG, "regular"), (stat.S_ISFIFO, "fifo"),
                       (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
                       (stat.S_ISSOCK, "socket"), (stat.S_ISDIR, "directory")):
        if test(mode):
            return kind
    return "special file"


def refuse_special(path, what=None):
    """The :func:`file_kind` of an output ``path``; AmfeError if amfe must not write it (a
    block device, a socket, a directory). what: how the message names it (default the path)."""
    kind = file_kind(path)
    if kind in REFUSED:
        raise AmfeError(f"cannot write {what or path}: it is a {kind}; amfe writes regular "
                        "files, FIFOs and character devices such as /dev/null")
    return kind


def own_stream(path):
    """1 or 2 when ``path`` is this process's stdout or stderr (/dev/stdout, /proc/self/fd/2, or
    the file either is redirected to), else None."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    for fd in (1, 2):
        try:
            other = os.fstat(fd)
        except OSError:
            continue
        if (st.st_dev, st.st_ino) == (other.st_dev, other.st_ino):
            return fd
    return None


def _write_through(path, write, by_name, check):
    """Write a FIFO or character device ``path`` through (see the module's docstring)."""
    with tempfile.TemporaryDirectory(prefix="amfe-out-") as scratch:
        tmp = os.path.join(scratch, "out")
        if by_name:
            write(tmp)
        else:
            with open(tmp, "wb") as fh:
                write(fh)
        if check is not None:
            check(tmp)
        fd = own_stream(path)
        try:
            with open(tmp, "rb") as src:
                if fd is not None:
                    for stream in (sys.stdout, sys.stderr):   # what was printed comes first
                        stream.flush()
                    with os.fdopen(os.dup(fd), "wb") as dst:
                        shutil.copyfileobj(src, dst)
                else:
                    with os.fdopen(os.open(path, os.O_WRONLY | os.O_NOCTTY), "wb") as dst:
                        shutil.copyfileobj(src, dst)
        except BrokenPipeError:
            if fd == 1:
                raise   # our own stdout's reader went away: the command ends quietly
            raise AmfeError(f"cannot write {path}: its reader closed it") from None
        except OSError as exc:
            if exc.errno in _NO_SPACE:
                raise NoSpaceError(f"no space left on {path}: the output could not be written "
                                   f"to it ({exc.strerror})", path) from None
            raise AmfeError(f"cannot write {path}: {exc.strerror or exc}") from None


def fsync_dir(directory):
    """fsync a directory (makes renames in it durable); best effort."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path, write, by_name=False, check=None, clean=True):
    """Write ``path`` through a temporary file in its directory, then os.replace it.

    write(fh) gets the open binary file, or with ``by_name`` write(tmp_path)
    gets the temporary file's name (for h5py). check(tmp_path), if given, runs
    on the finished temporary file before the rename and raises to refuse it.
    The file gets the usual umask permissions (not mkstemp's 0600). Orphaned
    temporary files of the same target are removed first (:func:`remove_stale_tmp`)
    unless ``clean`` is False (a caller that sweeps the directory once instead).
    On any error the temporary file is removed and the error re-raised, a full
    disk as AmfeError "no space left on DIR"; an existing ``path`` is left as it was.
    A symbolic link, a FIFO or a character device is written through, a block device or a
    socket refused (see the module's docstring); an empty name is an AmfeError.
    """
    path = os.fspath(path)
    if not path:
        raise AmfeError("cannot write a file with an empty name")
    kind = refuse_special(path)
    if kind in WRITTEN_THROUGH or (kind == "regular" and os.path.islink(path)
                                   and own_stream(path) is not None):
        return _write_through(path, write, by_name, check)
    if os.path.islink(path):   # keep the link: replace its target
        path = os.path.realpath(path)
    directory = os.path.dirname(os.path.abspath(path))
    existed = os.path.exists(path)
    if clean:
        remove_stale_tmp(path)
    prefix = f".{os.path.basename(path)}.{host_name()}-{os.getpid()}."
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=prefix, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            if by_name:
                write(tmp)
            else:
                write(fh)
                fh.flush()
                os.fsync(fh.fileno())
        if by_name:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        if check is not None:
            check(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            try:
                os.remove(tmp)
            except FileNotFoundError:
                pass
        if not isinstance(exc, AmfeError) and isinstance(exc, Exception) and is_no_space(exc):
            raise no_space_error(path, existed) from None
        raise
    fsync_dir(directory)


def atomic_write_h5(path, fill, base=None, check=None):
    """Write the HDF5 file ``path`` atomically; it is built in memory, then written as bytes.

    fill(f) gets an open h5py.File held in memory (h5py's core driver without
    a backing store); base: an HDF5 file to start from (read into memory,
    itself never changed). HDF5 itself never writes to the disk here, so a full
    disk is a plain write error (NoSpaceError) instead of an HDF5 library
    state that crashes the process at exit. Memory: about twice the file.
    check: as for :func:`atomic_write`.
    """
    import h5py

    name, mode = (os.fspath(base), "r+") if base is not None else (f"{path}.in-memory", "w")
    with h5py.File(name, mode, driver="core", backing_store=False) as f:
        fill(f)
        f.flush()
        image = f.id.get_file_image()
    atomic_write(path, lambda fh: fh.write(image), check=check)


def write_json(path, data):
    """Write ``data`` as indented JSON to ``path``; creates the directory if needed."""
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
    text = json.dumps(data, indent=2) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode()))

"""Atomic file writes: a reader, a crash or a kill never sees half a file.

Every file amfe writes goes through a temporary file in the target's
directory, is flushed and fsynced, and is renamed onto its final name with
os.replace; the directory is fsynced so the rename survives a power cut.
"""
import json
import os
import tempfile


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


def atomic_write(path, write, by_name=False):
    """Write ``path`` through a temporary file in its directory, then os.replace it.

    write(fh) gets the open binary file, or with ``by_name`` write(tmp_path)
    gets the temporary file's name (for h5py). The file gets the usual umask
    permissions (not mkstemp's 0600). On any error the temporary file is
    removed and the error re-raised; an existing ``path`` is left as it was.
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=directory, prefix="." + os.path.basename(path) + ".",
                               suffix=".tmp")
    try:
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
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except FileNotFoundError:
            pass
        raise
    fsync_dir(directory)


def write_json(path, data):
    """Write ``data`` as indented JSON to ``path``; creates the directory if needed."""
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
    text = json.dumps(data, indent=2) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode()))

"""amfe's C kernels: compiled once per machine with the system's C compiler, loaded by ctypes.

Imaging runs two loops that numpy cannot vectorise well: the union of sphere chords
(amfe/dataset/fill.c) and the bond finder (amfe/model/pairs.c). numba compiles them too,
but its import and its cache's load cost about 0.4 s a process, and its teardown 0.15-0.25
s more: most of a sweep's or a single prediction's time. A C library loads in about a
millisecond. The source is compiled on first use (about 0.5 s) with ``$CC`` (default
``cc``; run/setup.sh installs gcc) into ``$AMFE_CACHE_DIR`` (default
``$XDG_CACHE_HOME/amfe`` or ``~/.cache/amfe``), under a name that holds a hash of the
source, the flags and the compiler (its file's size and time), so an edited kernel is
rebuilt, and ranks that start together share one build (each writes its own temporary
file and renames it).

Floating point: ``-O2 -ffp-contract=off`` and no fast-math, so every operation is the
IEEE one the numpy path does, in its order (no fused multiply-adds): the kernels give
the numpy path's results bit for bit (tests/test_pixelkernel.py). ``-fno-math-errno``
lets sqrt be one instruction (the kernels take no root of a negative number): 13 % off
the union kernel's time. Where no compiler works, :func:`library` returns None and the
callers take numba or numpy.
"""
import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from functools import cache
from pathlib import Path

import numpy as np

#: ctypes argument types of the kernels' arrays (C-contiguous int64 and float64).
I64 = np.ctypeslib.ndpointer(np.int64, flags="C_CONTIGUOUS")
F64 = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
FLAGS = ("-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off", "-fno-fast-math",
         "-fno-math-errno")


def cache_dir():
    """The folder of the built kernels (module docstring)."""
    if os.environ.get("AMFE_CACHE_DIR"):
        return Path(os.environ["AMFE_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "amfe"


def _build(source, target, cc):
    """Compile ``source`` to ``target`` through a temporary file renamed into place; True if
    it built."""
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=target.stem + ".", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        out = subprocess.run([cc, *FLAGS, "-o", tmp, str(source), "-lm"], capture_output=True,
                             text=True, timeout=300)
        if out.returncode != 0:
            return False
        os.replace(tmp, target)
        return True
    except (OSError, subprocess.SubprocessError):
        return False
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


@cache
def library(source):
    """ctypes.CDLL of the C file ``source`` (a path), built on first use; None where it
    cannot be built or loaded (no compiler, an unwritable cache on every choice)."""
    if os.environ.get("AMFE_NO_C") == "1":   # the numba and numpy paths, for tests
        return None
    source = Path(source)
    cc = shutil.which(os.environ.get("CC", "cc"))
    if cc is None:
        return None
    real = os.path.realpath(cc)   # the compiler itself (an upgrade changes its size or time)
    stat = os.stat(real)
    digest = hashlib.sha256(source.read_bytes()
                            + repr((FLAGS, real, stat.st_size, stat.st_mtime_ns)).encode())
    name = f"{source.stem}-{digest.hexdigest()[:20]}.so"
    for folder in (cache_dir(), Path(tempfile.gettempdir()) / f"amfe-{os.getuid()}"):
        target = folder / name
        try:
            if target.is_file() or _build(source, target, cc):
                return ctypes.CDLL(str(target))
        except OSError:
            continue
    return None


def function(source, name, restype, argtypes):
    """The C function ``name`` of the C file ``source`` with its ctypes signature, or None
    where :func:`library` cannot build it."""
    lib = library(source)
    if lib is None:
        return None
    fn = getattr(lib, name)
    fn.restype, fn.argtypes = restype, list(argtypes)
    return fn

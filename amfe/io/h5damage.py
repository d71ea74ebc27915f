"""One line for an HDF5 file whose bytes are damaged (docs/hard_cases.md, issue 45 item 9).

h5py reports a corrupt compressed chunk as ``OSError: Can't read data (inflate() failed)``
from deep inside a read; :func:`damaged` turns that (and any other OSError or RuntimeError of
a read) into an AmfeError that names the file and what to do. :func:`read_every_chunk`
reads a file's every chunk, so a check finds a damaged chunk that a partial read would miss.
h5py is imported only inside the functions (``import amfe`` must not import it).
"""
import contextlib
import os

from amfe.errors import AmfeError


@contextlib.contextmanager
def damaged(path, what, fix):
    """Run the block; an OSError or RuntimeError from HDF5 becomes one AmfeError line:
    "cannot read WHAT PATH: REASON (a damaged or truncated file); FIX"."""
    try:
        yield
    except (OSError, RuntimeError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise AmfeError(f"cannot read {what} {os.fspath(path)}: {reason} (a damaged or "
                        f"truncated file); {fix}") from None


def read_every_chunk(f):
    """Read every dataset of the open h5py file ``f`` chunk by chunk (memory: one chunk).

    Raises what HDF5 raises for a damaged chunk (wrap the call in :func:`damaged`).
    Returns the number of datasets read.
    """
    import h5py
    found = []
    f.visititems(lambda name, obj: found.append(obj) if isinstance(obj, h5py.Dataset) else None)
    for ds in found:
        if ds.shape is None or ds.size == 0:
            continue
        if ds.chunks is None:
            ds[()]
        else:
            for sel in ds.iter_chunks():
                ds[sel]
    return len(found)

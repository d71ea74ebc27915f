"""MPI helpers every layer can use: compute on rank 0 and hand the result (or the error) to all.

A function that fails on rank 0 only would leave the other ranks waiting in
the next collective. :func:`on_root` runs a function on rank 0 of a
communicator, broadcasts its value, or its :class:`~amfe.errors.AmfeError`,
and every rank returns the value or raises the same error (same class, same
message). Works without mpi4py installed (one process).
"""
from amfe.errors import AmfeError


def on_root(comm, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` evaluated on rank 0 of ``comm``, returned on every rank.

    comm: an mpi4py communicator, or None for a single process. An
    :class:`~amfe.errors.AmfeError` raised on rank 0 (or any subclass) is
    raised on every rank with its class kept. Other exceptions propagate on
    rank 0 only (a bug, not bad input: the CLI aborts the job on them).
    """
    if comm is None or comm.size == 1:
        return fn(*args, **kwargs)
    payload = None
    if comm.rank == 0:
        try:
            payload = ("ok", fn(*args, **kwargs))
        except AmfeError as exc:
            payload = ("error", exc)
    return unwrap(comm.bcast(payload, root=0))


def unwrap(payload):
    """Return the value of an ("ok", value) payload, or raise its ("error", exc)."""
    kind, value = payload
    if kind == "error":
        raise value
    return value


def as_payload(fn, *args, **kwargs):
    """("ok", fn(...)) or ("error", the AmfeError it raised): a broadcastable outcome."""
    try:
        return ("ok", fn(*args, **kwargs))
    except AmfeError as exc:
        return ("error", exc)

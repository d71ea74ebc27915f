"""MPI helpers every layer can use: compute on rank 0 and hand the result (or the error) to all.

A function that fails on rank 0 only would leave the other ranks waiting in
the next collective. :func:`on_root` runs a function on rank 0 of a
communicator, broadcasts its value, or its :class:`~amfe.errors.AmfeError`,
and every rank returns the value or raises the same error (same class, same
message). :func:`same_on_every_rank` checks, in one collective, that every
rank passed the same arguments that decide which collectives come next.
:func:`abort_on_uncaught` ends every rank when one dies of an exception outside
amfe (a user's script under mpirun). Works without mpi4py installed (one process).
"""
import sys

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


def same_on_every_rank(comm, values):
    """AmfeError on every rank of ``comm`` unless ``values`` ({name: picklable value}) is the
    same on all of them (one allgather; nothing on a single process). The arguments that
    decide a solve's first collectives (a bed's path, read on rank 0 and broadcast, against
    arrays checked by an allgather) must agree before those collectives, or the ranks would
    pair unlike collectives: a hang, or garbage."""
    if comm is None or comm.size == 1:
        return
    every = comm.allgather(values)
    for rank, theirs in enumerate(every):
        for name in values:
            if theirs[name] != every[0][name]:
                raise AmfeError(f"{name} differs across ranks: rank 0 passes {every[0][name]}, "
                                f"rank {rank} {theirs[name]}; every rank must pass the same")


def abort_on_uncaught():
    """Install a sys.excepthook that, after the usual traceback, calls MPI_Abort when MPI runs
    on more than one rank (as ``python -m mpi4py`` does): a rank of a user's script that dies
    of an exception (an AmfeError from ``amfe.Bed`` built from NaN on that rank only) would
    otherwise leave the others waiting in amfe's first collective for ever."""
    previous = sys.excepthook
    if getattr(previous, "amfe_aborts", False):
        return

    def hook(kind, value, tb):
        previous(kind, value, tb)
        mpi = sys.modules.get("mpi4py.MPI")
        try:
            alive = mpi is not None and mpi.Is_initialized() and not mpi.Is_finalized()
            if alive and mpi.COMM_WORLD.size > 1:
                sys.stderr.flush()
                mpi.COMM_WORLD.Abort(1)
        except Exception:  # noqa: BLE001 - a hook must not fail in its turn
            pass
    hook.amfe_aborts = True
    sys.excepthook = hook

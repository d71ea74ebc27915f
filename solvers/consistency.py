"""Every rank must hand a collective solve the same input: checked once, before any collective.

Under mpirun each rank calls :func:`amfe.solvers.driver.homogenize_bed` with
its own arrays. Different arrays on different ranks (a seed taken from the
rank, NaN on one rank, one particle fewer) would mix two beds into one wrong
number, or leave one rank waiting in a collective the others never enter.
:func:`agree_across_ranks` compares, in one ``allgather`` of a few hundred
bytes per rank, a 64-bit blake2b digest of each input's bytes (dtype and
shape included) and each rank's own verdict on its input (the AmfeError that
validating it raised, if any). On any difference every rank raises the same
AmfeError; otherwise every rank raises the same validation error, or none.
The gather also carries each rank's host and physical memory, for the
memory limit summed over machines.
"""
import hashlib
import socket

import numpy as np

from amfe.errors import AmfeError
from amfe.model.memory import machine_memory


def digest(value):
    """A 64-bit content hash of ``value``: array bytes with dtype and shape, else its repr."""
    h = hashlib.blake2b(digest_size=8)
    try:
        arr = np.asarray(value)
    except Exception:  # noqa: BLE001 - ragged lists and the like: hashed by their repr
        arr = None
    if arr is not None and arr.dtype.kind in "biufc":
        h.update(f"{arr.dtype.str}{arr.shape}".encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    else:
        h.update(repr(value).encode())
    return int.from_bytes(h.digest(), "little")


def _shape(value):
    try:
        return tuple(np.shape(value))
    except Exception:  # noqa: BLE001
        return None


def agree_across_ranks(mpi, inputs, error=None):
    """Raise the same AmfeError on every rank unless all ranks hold the same ``inputs``.

    mpi: an mpi4py communicator (or None: one process); inputs: {name:
    value} (arrays, materials, option dicts); error: the AmfeError this rank
    met validating its input, or None. Collective: one allgather. Returns
    [(host, physical memory [bytes]) per rank] when the ranks agree and none
    had an error; raises ``error`` (the same on every rank) when the ranks
    agree on the input and it is bad.
    """
    record = {"digests": [digest(v) for v in inputs.values()],
              "shapes": [_shape(v) for v in inputs.values()],
              "error": None if error is None else (type(error).__name__, str(error)),
              "host": (socket.gethostname(), machine_memory())}
    records = [record] if mpi is None or mpi.size == 1 else mpi.allgather(record)
    names = list(inputs)
    differ = [k for k in range(len(names)) if len({r["digests"][k] for r in records}) > 1]
    if differ:
        raise AmfeError(_mismatch(names, differ, records))
    errors = {r["error"] for r in records}
    if errors != {None}:
        if error is not None and len(errors) == 1:
            raise error  # the same bad input on every rank: its own message, its own class
        first = next(r["error"] for r in records if r["error"] is not None)
        ranks = [k for k, r in enumerate(records) if r["error"] is not None]
        raise AmfeError(f"rank(s) {', '.join(map(str, ranks))} of {len(records)} refused the "
                        f"input and the others did not: {first[1]}")
    return [r["host"] for r in records]


def _mismatch(names, differ, records):
    parts = []
    for k in differ:
        shapes = [r["shapes"][k] for r in records]
        if len(set(shapes)) > 1:
            parts.append(f"{names[k]} (shapes " + ", ".join(
                f"rank {i}: {s}" for i, s in enumerate(shapes)) + ")")
        else:
            groups = {}
            for i, r in enumerate(records):
                groups.setdefault(r["digests"][k], []).append(i)
            same = f"same shape {shapes[0]}, " if shapes[0] else ""
            parts.append(f"{names[k]} ({same}different values; ranks with equal ones: "
                         + " | ".join(",".join(map(str, g)) for g in groups.values()) + ")")
    refused = [(k, r["error"][1]) for k, r in enumerate(records) if r["error"] is not None]
    if refused:
        parts.append(f"rank {refused[0][0]} refused its input: {refused[0][1]}")
    return (f"the {len(records)} MPI ranks were given different inputs: "
            + "; ".join(parts) + ". Every rank must pass bit-identical arrays, material and "
            "options (generate the bed with the same seed on every rank, or read it on rank 0 "
            "and broadcast it); nothing was solved")

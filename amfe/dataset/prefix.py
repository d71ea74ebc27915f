"""The first records of a running or interrupted data set, as a data-set file of their own.

A data set's record k is a pure function of (seed, k) (amfe.model.scales.record_seed),
so its records 0..N-1 are exactly the data set ``amfe dataset --count N`` with the
same seed would make. :func:`write_prefix` writes them from the part files of a
run still in progress (or killed), from a finished file, or from both while a
finished file grows, without touching the run: training can start
on the first thousands of beds while the rest are labelled (docs/datasets.md).
"""
import os

from amfe.dataset.merge import merge_parts
from amfe.dataset.parts import done_indices, file_params, parts_dir, read_params_json
from amfe.errors import AmfeError
from amfe.io.paths import check_output


def finished_prefix(parts, count, start=0):
    """The number N of records 0..N-1 that all exist: those below ``start`` (the rows of a
    finished file being grown) and the part files in ``parts`` from ``start`` on."""
    n = start
    for k in done_indices(parts, count):
        if k < start:
            continue
        if k != n:
            return n
        n += 1
    return n


def _finished_rows(source):
    """(run parameters, count) of the finished data-set file ``source``, or (None, 0)."""
    if not os.path.isfile(source):
        return None, 0
    import h5py

    try:
        with h5py.File(source, "r") as f:
            attrs = dict(f.attrs)
    except OSError as exc:
        raise AmfeError(f"--prefix-of: {source} is not a data set ({exc})") from None
    if "count" not in attrs or "seed" not in attrs:
        raise AmfeError(f"--prefix-of: {source} is not a data set (no count or seed attribute)")
    return file_params(attrs, ("label_rule_version",)), int(attrs["count"])


def write_prefix(source, output, count=None):
    """Write records 0..count-1 of the data set made at ``source`` into ``output``.

    source: the run's output path: its parts are in ``SOURCE.parts`` while it
    is being made, the rows in ``SOURCE`` once it is finished, and both while
    a finished one grows. count: how many; default all of the finished
    prefix. Returns the count. AmfeError when there is no such data set, or
    fewer than ``count`` records finished in a row.
    """
    parts = parts_dir(source)
    params = read_params_json(parts) if os.path.isdir(parts) else None
    whole, base = _finished_rows(source)
    if params is None and whole is None:
        raise AmfeError(f"--prefix-of: there is no data set being made at {source} ({parts} is "
                        "missing)")
    if params is None or int(params["count"]) <= base:   # finished (stale parts: a kill)
        params = whole
    n = finished_prefix(parts, int(params["count"]), base)
    if count is None:
        count = n
    if count < 1 or count > n:
        raise AmfeError(f"--prefix-of: {count} record(s) asked, but only records 0..{n - 1} of "
                        f"{source} are finished in a row ({n}); ask for at most {n}"
                        if n else f"--prefix-of: record 0 of {source} is not finished yet")
    check_output(output, inputs=(source,))
    merge_parts(output, parts, params, first=count, base=(source, base) if base else None)
    return count

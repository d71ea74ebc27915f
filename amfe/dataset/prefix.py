"""The first records of a running or interrupted data set, as a data-set file of their own.

A data set's record k is a pure function of (seed, k) (amfe.model.scales.record_seed),
so its records 0..N-1 are exactly the data set ``amfe dataset --count N`` with the
same seed would make. :func:`write_prefix` writes them from the part files of a
run still in progress (or killed), without touching the run: training can start
on the first thousands of beds while the rest are labelled (docs/datasets.md).
"""
import os

from amfe.dataset.merge import merge_parts
from amfe.dataset.parts import done_indices, parts_dir, read_params_json
from amfe.errors import AmfeError
from amfe.io.paths import check_output


def finished_prefix(parts, count):
    """The number N of records 0..N-1 that all have a part file in ``parts``."""
    n = 0
    for n, k in enumerate(done_indices(parts, count)):
        if k != n:
            return n
    return len(done_indices(parts, count))


def write_prefix(source, output, count=None):
    """Write records 0..count-1 of the data set being made at ``source`` into ``output``.

    source: the run's output path (its parts are in ``SOURCE.parts``).
    count: how many; default all of the finished prefix. Returns the count.
    AmfeError when there are no parts, or fewer than ``count`` finished in a row.
    """
    parts = parts_dir(source)
    params = read_params_json(parts) if os.path.isdir(parts) else None
    if params is None:
        why = (f"{source} is finished (its records are merged): read its rows instead, e.g. "
               "amfe train --max-train N" if os.path.isfile(source)
               else f"there is no data set being made at {source} ({parts} is missing)")
        raise AmfeError(f"--prefix-of: {why}")
    n = finished_prefix(parts, int(params["count"]))
    if count is None:
        count = n
    if count < 1 or count > n:
        raise AmfeError(f"--prefix-of: {count} record(s) asked, but only records 0..{n - 1} of "
                        f"{source} are finished in a row ({n}); ask for at most {n}"
                        if n else f"--prefix-of: record 0 of {source} is not finished yet")
    check_output(output, inputs=(source,))
    merge_parts(output, parts, params, first=count)
    return count

"""What ``amfe dataset`` checks before any work and decides on world rank 0 under the lock.

:func:`check_arguments` refuses bad options on every rank alike, before any
file is touched. :func:`prepare` (world rank 0, with the output's lock held,
:mod:`amfe.dataset.lock`) decides what to do: nothing for a finished file of
the count asked; for a larger count, the records beyond the finished file's
(it grows: its records are kept); else the records still missing from the
parts directory; each time after moving any part that is not the record it
claims to be to ``OUTPUT.rejected/``.
:func:`failed_share_error` is the verdict on the finished file.
"""
import math
import os
from dataclasses import dataclass

import numpy as np

from amfe.dataset.datacheck import check_dataset
from amfe.dataset.images import IMAGING_VERSION
from amfe.dataset.parts import (
    LABEL_RULE_VERSION,
    STATUS_OK,
    describe_params,
    done_indices,
    file_params,
    param_differences,
    part_path,
    part_problem,
    parts_dir,
    read_params_json,
    reject_part,
    remove_parts,
    same_but_count,
    write_params_json,
)
from amfe.errors import AmfeError, _list_items
from amfe.io.atomic import is_no_space, no_space_error, remove_stale_tmp

#: Data-set seeds are stored as an HDF5 uint64 attribute; record_seed takes any of them.
SEED_LIMIT = 2**64
#: Part files are numbered with 8 digits; 10^7 small beds are ~170 core-days already.
MAX_COUNT = 10**7
DEFAULT_MAX_FAILED_SHARE = 0.05


@dataclass(frozen=True)
class DatasetOptions:
    """What ``amfe dataset`` makes, beside the output and the count (checked by
    :func:`check_arguments`): the data-set seed and scale, rank groups, the
    labels' solve (rtol None: the solver's default), boundary conditions and bond
    springs ("paper" or "continuum", amfe.model.continuum_springs),
    the failure budget, and ``from_labels``: label tables (paths) whose labels
    the records copy instead of solving (:mod:`amfe.dataset.labels`);
    ``solve_rest``: with tables, records beyond theirs are solved with the
    tables' method (a labelling run continued from its committed tables)."""

    seed: int = 0
    scale: str = "small"
    ranks_per_bed: int = 1
    rtol: float = None
    solver: str = "auto"
    bc: str = "kubc"
    springs: str = "paper"
    max_failed_share: float = DEFAULT_MAX_FAILED_SHARE
    from_labels: tuple = ()
    solve_rest: bool = False


def _is_int(x):
    return not isinstance(x, bool) and isinstance(x, (int, np.integer))


def check_arguments(count, seed, ranks_per_bed, rtol, max_failed_share, world_size):
    """AmfeError for any option out of range (the same on every rank); nothing else."""
    if not _is_int(count) or not 1 <= count <= MAX_COUNT:
        raise AmfeError(f"--count must be an integer in [1, {MAX_COUNT}], got {count!r}; make "
                        "several data sets for more")
    if not _is_int(seed) or not 0 <= seed < SEED_LIMIT:
        raise AmfeError(f"--seed must be an integer with 0 <= seed < 2**64 "
                        f"({SEED_LIMIT}), got {seed!r}")
    if not _is_int(ranks_per_bed) or not 1 <= ranks_per_bed <= world_size:
        raise AmfeError(f"--ranks-per-bed must lie in [1, {world_size}] (the number of MPI "
                        f"ranks), got {ranks_per_bed}")
    if not 0.0 < _float(rtol) < 1.0:
        raise AmfeError(f"--rtol must lie in (0, 1), got {rtol}")
    share = _float(max_failed_share)
    if not (math.isfinite(share) and 0.0 <= share <= 1.0):
        raise AmfeError(f"--max-failed-share must lie in [0, 1], got {max_failed_share}")


def _float(x):
    """float(x), or NaN for what is not a real number (refused by the range checks)."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _same_run(attrs, params):
    try:
        return (str(attrs.get("scale")) == params["scale"]
                and int(attrs.get("seed")) == params["seed"]
                and int(attrs.get("count")) == params["count"]
                and float(attrs.get("rtol")) == params["rtol"]
                and str(attrs.get("solver", "gamg")) == params.get("solver", "gamg")
                and str(attrs.get("bc", "kubc")) == params.get("bc", "kubc")
                and str(attrs.get("springs", "")) == params.get("springs", ""))
    except (TypeError, ValueError):
        return False


def _finished_file(output, params):
    """The plan for an existing ``output``: complete (and checked), grown, or an AmfeError."""
    try:
        problems, data, attrs = check_dataset(output)
    except AmfeError as exc:
        raise AmfeError(f"{output} exists and is not a data set ({exc}); remove it or "
                        "choose another -o") from None
    if problems:
        raise AmfeError(f"{output} exists but fails its check ({'; '.join(problems)}); "
                        "remove it to make it again")
    if _same_run(attrs, params):
        parts = parts_dir(output)
        pending = read_params_json(parts) if os.path.isdir(parts) else None
        if not isinstance(pending, dict) or int(pending.get("count", 0)) <= int(attrs["count"]):
            remove_parts(parts)  # left by a kill between the merge's rename and this
        # else: the new records of a grow to more, kept for the run that resumes it
        return {"complete": True, "data": data, "attrs": attrs}
    return _unfinished(output, params, base=_growable(output, attrs, params))


def _growable(output, attrs, params):
    """The records of finished file ``output`` that a run of ``params`` keeps (its count),
    or an AmfeError: fewer records asked, or any other parameter, label rule or imaging
    version differs (record k is a function of those, the seed and k alone)."""
    old = file_params(attrs, ("label_rule_version",) if "label_rule_version" in params else ())
    n = int(attrs["count"])
    differ = param_differences(old, params)
    for name, now in (("label_rule_version", LABEL_RULE_VERSION),
                      ("imaging_version", IMAGING_VERSION)):
        made = int(attrs.get(name, 1))   # files made before the attribute existed: 1
        if made != now and name not in params:
            differ.append(f"{name} {made} (this amfe makes {now})")
    if differ:
        raise AmfeError(f"{output} exists and was made with other parameters: "
                        f"{'; '.join(differ)}; rerun with those to grow it, or remove it or "
                        "choose another -o")
    if params["count"] < n:
        raise AmfeError(f"{output} holds {n} records, more than the {params['count']} asked; "
                        f"take its first records with `amfe dataset --prefix-of {output} -o "
                        f"FIRST.h5 --count {params['count']}`")
    return n


def prepare(output, params):
    """World rank 0, lock held: a plan dict {complete, ...}; AmfeError if the run must not start.

    For an unfinished run: todo (sorted record indices without a valid
    part), n_done, parts, rejected [(k, why, new path)] for the parts moved
    aside to ``OUTPUT.rejected/``, grown_from (the run's earlier count when
    this call grows it: same parameters, more records; else None), base (the
    records 0..base-1 that a finished ``output`` grown by this run keeps, 0
    for none: the parts hold only records from base on).
    """
    output = os.fspath(output)
    try:
        if os.path.exists(output):
            return _finished_file(output, params)
        return _unfinished(output, params)
    except OSError as exc:
        if is_no_space(exc):
            raise no_space_error(parts_dir(output), False) from None
        raise AmfeError(f"cannot prepare {output}: {exc.strerror or exc}") from None


def _unfinished(output, params, base=0):
    parts = parts_dir(output)
    os.makedirs(parts, exist_ok=True)
    old = read_params_json(parts)
    grown_from = base or None
    done = [k for k in done_indices(parts, params["count"]) if k >= base]
    if old is None:
        if done:
            raise AmfeError(f"{parts} holds records but no {os.path.basename(parts)}/params.json; "
                            "remove the directory to start afresh")
        write_params_json(parts, params)
    elif old != params:
        grown_from = _grow(parts, old, params)
    remove_stale_tmp(parts, every_target=True)   # of killed writers; the lock keeps live ones out
    rejected = []
    for k in done:
        path = part_path(parts, k)
        why = part_problem(path, k, params)
        if why is not None:
            rejected.append((k, why, reject_part(path, output)))
    bad = {k for k, _, _ in rejected}
    good = [k for k in done if k not in bad]
    todo = sorted(set(range(base, params["count"])) - set(good))
    return {"complete": False, "todo": todo, "n_done": base + len(good), "parts": parts,
            "rejected": rejected, "grown_from": grown_from, "base": base}


def _grow(parts, old, params):
    """Let an unfinished run of ``old`` parameters go on as ``params`` when only its count grows.

    Returns the old count (its parts stay: part_problem ignores the count);
    AmfeError for any other change, or for fewer records (--prefix-of takes those).
    """
    if not same_but_count(old, params):
        raise AmfeError(f"{parts} belongs to a run with other parameters ({describe_params(old)}; "
                        f"asked: {describe_params(params)}): rerun with those, or remove "
                        f"{parts} to start afresh")
    if params["count"] < old["count"]:
        raise AmfeError(f"{parts} belongs to a run of {old['count']} records, more than the "
                        f"{params['count']} asked; rerun with --count {old['count']}, or take "
                        f"its first records with `amfe dataset --prefix-of`")
    write_params_json(parts, params)
    return old["count"]


def rejected_lines(rejected, limit=5):
    """Lines that say which part files were refused, why, and where they are now."""
    lines = [f"amfe dataset: refused record file of record {k} ({why}); moved to {dest}; it is "
             "computed again" for k, why, dest in rejected[:limit]]
    if len(rejected) > limit:
        lines.append(f"amfe dataset: ... and {len(rejected) - limit} more refused record files "
                     f"in {os.path.dirname(rejected[0][2])}")
    return lines


def failed_share_error(output, data, max_failed_share):
    """The message when more than ``max_failed_share`` of the records failed, else None."""
    status = np.asarray(data["status"])
    failed = np.flatnonzero(status != STATUS_OK)
    M = status.shape[0]
    if M == 0 or failed.size <= max_failed_share * M:
        return None
    index = np.asarray(data["index"])[failed]
    return (f"{failed.size} of {M} records failed ({100 * failed.size / M:.1f} % > "
            f"--max-failed-share {100 * max_failed_share:g} %): records "
            f"{_list_items(index.tolist(), 10)} (reasons in the summary above); {output} is "
            "written: check the failures before using it, or raise --max-failed-share")

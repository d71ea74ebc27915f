"""The plumbing every script in run/ shares: the repository's root, an argument parser,
markdown tables, JSON output, data-set record ranges and the joining of members trained
apart, so that no script carries its own copy.

Scripts run from the repository root as modules (``python -m run.bench.solver``), so they
import this module and each other as ``run.<folder>.<script>``: no ``sys.path`` edits.
"""
import argparse
import json
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
"""The repository's root (the folder that holds run/, docs/ and tests/)."""


def parser(doc):
    """An ArgumentParser whose description is the first paragraph of ``doc`` (a module's
    docstring) and whose epilog is the rest, as written (its usage lines)."""
    head, _, rest = (doc or "").strip().partition("\n\n")
    return argparse.ArgumentParser(description=head, epilog=rest or None,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def md_table(header, rows, align=None):
    """A markdown table (str, no trailing newline): ``header`` (list of str) and ``rows`` (lists
    of cells, str() each); ``align``: a string of "l", "r", "c" per column (default all left)."""
    marks = {"l": "---", "r": "---:", "c": ":---:"}
    align = align or "l" * len(header)
    lines = ["| " + " | ".join(map(str, header)) + " |",
             "|" + "|".join(marks[a] for a in align) + "|"]
    lines += ["| " + " | ".join(map(str, row)) + " |" for row in rows]
    return "\n".join(lines)


def write_json(path, data):
    """``data`` as indented JSON to ``path`` (its directory made), atomically."""
    from amfe.io.atomic import write_json as atomic_json
    atomic_json(path, data)


def read_json(path):
    with open(path) as f:
        return json.load(f)


def record_spec(spec):
    """(path, keep) of a ``PATH[:RANGES]`` data-set argument: RANGES is ``START`` (records
    START on) or comma-separated ``A-B`` (records A to B inclusive), in record positions of
    the data set; ``keep(positions)`` -> bool array of the positions selected (all if none).

    >>> path, keep = record_spec("D.h5:0-1,3-4"); path, keep(range(6)).tolist()
    ('D.h5', [True, True, False, True, True, False])
    """
    path, _, ranges = spec.rpartition(":") if ":" in spec else (spec, "", "")
    bounds = []
    for part in filter(None, ranges.split(",")):
        a, dash, b = part.partition("-")
        try:
            lo, hi = int(a), (int(b) if dash else None)
        except ValueError:
            raise SystemExit(f"error: {spec!r}: record ranges are START or A-B[,C-D]")
        bounds.append((lo, hi))

    def keep(positions):
        pos = np.asarray(positions)
        if not bounds:
            return np.ones(pos.shape, bool)
        return np.any([(pos >= lo) & ((pos <= hi) if hi is not None else True)
                       for lo, hi in bounds], axis=0)
    return path, keep


def join_members(parts, data, block, agree=None):
    """(states, histories, seeds, seconds, the last part's ``block``) of the checkpoints
    ``parts``, members trained apart (``--members K`` in each) on ``data`` (the ``--data``
    list); ``block``: the checkpoint's key holding its training record ("anybed", "thick");
    ``agree``: {key: value} of that record every part must hold as the joining command gives
    it (train_thick's augment, which decides how the joined network reads a bed). SystemExit
    for a part trained on other data or otherwise."""
    from amfe.training.checkpoint import load_checkpoint
    states, histories, seeds, seconds, record = [], [], [], 0.0, None
    for part in parts:
        c = load_checkpoint(part)
        record = c[block]
        if record["data"] != list(data):
            raise SystemExit(f"error: {part} was trained on {record['data']}, not --data")
        for key, want in (agree or {}).items():
            if record.get(key) != want:
                raise SystemExit(f"error: {part} was trained with --{key} {record.get(key)}, "
                                 f"not --{key} {want}")
        states += c["members"]
        histories += c["history"]
        seeds += c["member_seeds"]
        seconds += record["seconds"]
    return states, histories, seeds, seconds, record

"""The plumbing every script in run/ shares: the repository's root, an argument parser,
markdown tables and JSON output, so that no script carries its own copy.

Scripts run from the repository root as modules (``python -m run.bench.solver``), so they
import this module and each other as ``run.<folder>.<script>``: no ``sys.path`` edits.
"""
import argparse
import json
import os

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

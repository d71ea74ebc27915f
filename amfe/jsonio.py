"""JSON output, written atomically (amfe.atomicio)."""
import json
import os

from .atomicio import atomic_write


def write_json(path, data):
    """Write ``data`` as indented JSON to ``path``; creates the directory if needed."""
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
    text = json.dumps(data, indent=2) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode()))

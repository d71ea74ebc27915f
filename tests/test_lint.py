"""ruff (pyproject.toml's [tool.ruff]) is clean on the package and the tests: style, pyflakes,
import order, and imports at the top but for the heavy or optional libraries (issue 44)."""
import subprocess
import sys

from helpers import ROOT


def test_ruff_is_clean():
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "amfe", "solvers",
                           "training", "tests"], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]


def test_ruff_would_catch_a_fault(tmp_path):
    """The configuration's rules do fire: an unused import and an import inside a function."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f():\n    import json\n    return json\n")
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config",
                           f"{ROOT}/pyproject.toml",
                           str(bad)], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 1 and "F401" in proc.stdout and "PLC0415" in proc.stdout

"""docs/tutorial.md runs as written: every code block, in order, in a fresh directory."""
import os
import re
import subprocess
import sys

from helpers import MPI_ENV, ROOT

TUTORIAL = os.path.join(ROOT, "docs", "tutorial.md")


def blocks():
    """[(language, code)] of the tutorial's fenced blocks, in order."""
    with open(TUTORIAL) as f:
        text = f.read()
    return re.findall(r"```(bash|python)\n(.*?)```", text, flags=re.S)


def test_the_tutorial_runs_as_written(tmp_path):
    env = dict(MPI_ENV, PATH=os.path.dirname(sys.executable) + os.pathsep + MPI_ENV["PATH"])
    found = blocks()
    assert [lang for lang, _ in found].count("bash") >= 5 and found[-1][0] == "python"
    for lang, code in found:
        if "source run/env.sh" in code:   # the reader's own set-up: the test's env does it
            continue
        cmd = ["bash", "-euo", "pipefail", "-c", code] if lang == "bash" else [
            sys.executable, "-c", code]
        proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, f"{code}\n{proc.stdout}\n{proc.stderr}"
        if lang == "python":
            assert proc.stdout.strip().endswith("True"), proc.stdout
    for made in ("bed.h5", "result.json", "vtu/cases.pvd", "vtu/view_xx_axial_force.png",
                 "prediction.json", "sweep/points.csv", "sweep/sweep_Ex.png"):
        assert (tmp_path / made).is_file(), made

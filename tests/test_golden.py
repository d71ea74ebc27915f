"""The main job's command gives the same JSON as the recorded one, byte for byte.

tests/data/golden_result_*.json were written by the code before the refactor of issue 29
(`python tests/test_golden.py --regenerate`, on the unmodified code); only the
timings (keys ending in ``seconds``) are blanked before the comparison. An issue
that changes a number on purpose regenerates them and says so.
"""
import json
import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from helpers import ROOT, run_cli  # noqa: E402

DATA = os.path.join(ROOT, "tests", "data")

#: name -> (ranks, arguments after `amfe homogenize`); the bed paths are relative to
#: the run's directory, so that the JSON's paths do not depend on where it ran
RUNS = {
    # run/main.sh's command on a small bed
    "kubc_2ranks": (2, ["golden_bed.h5", "-o", "result.json", "--vtu", "vtu"]),
    # the bounds report of run/main.sh, with every condition and the diagnostics
    "all_periodic": (1, ["golden_bed_periodic.h5", "--bc", "all", "--quiet", "--diagnose",
                         "-o", "result.json"]),
    "mixed_gamg": (1, ["golden_bed.h5", "--bc", "mixed", "--solver", "gamg", "--quiet",
                       "-o", "result.json", "-amfe_block", "no"]),
}


def blank_timings(value):
    """The JSON value with every number under a key ending in "seconds" set to 0."""
    if isinstance(value, dict):
        return {k: (_zero(v) if k.endswith("seconds") else blank_timings(v))
                for k, v in value.items()}
    if isinstance(value, list):
        return [blank_timings(v) for v in value]
    return value


def _zero(v):
    return [_zero(x) for x in v] if isinstance(v, list) else 0


def normalised(path):
    """The JSON text of a result file with its timings blanked."""
    with open(path) as f:
        return json.dumps(blank_timings(json.load(f)), indent=2) + "\n"


def write_bed_file(source, path):
    """The bed file ``path`` from its JSON record (centres, radii and attributes, from
    `amfe pack`; JSON because the repository keeps no HDF5 files)."""
    import numpy as np

    from amfe.io.bedfile import write_bed
    from amfe.model.bed import Bed

    with open(source) as f:
        d = json.load(f)
    write_bed(path, Bed(np.array(d["centers"]), np.array(d["radii"]), d["attrs"]))


def run(name, directory):
    """Run one golden command in ``directory``; the normalised JSON text."""
    ranks, args = RUNS[name]
    for bed in ("golden_bed", "golden_bed_periodic"):
        write_bed_file(os.path.join(DATA, bed + ".json"), os.path.join(directory, bed + ".h5"))
    proc = run_cli(["homogenize", *args], ranks=ranks if ranks > 1 else None, cwd=directory)
    assert proc.returncode == 0, proc.stderr
    return normalised(os.path.join(directory, "result.json"))


@pytest.mark.mpi
@pytest.mark.parametrize("name", sorted(RUNS))
def test_same_json_as_before(name, tmp_path):
    with open(os.path.join(DATA, f"golden_result_{name}.json")) as f:
        expected = f.read()
    assert run(name, str(tmp_path)) == expected


if __name__ == "__main__" and sys.argv[1:] == ["--regenerate"]:
    import tempfile
    for name in RUNS:
        with tempfile.TemporaryDirectory() as tmp:
            text = run(name, tmp)
        with open(os.path.join(DATA, f"golden_result_{name}.json"), "w") as f:
            f.write(text)
        print("wrote", f"golden_result_{name}.json")

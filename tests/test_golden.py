"""The main job's command gives the same JSON as the recorded one, byte for byte.

tests/data/golden_result_*.json were written by the code before the refactor of issue 29
(`python tests/test_golden.py --regenerate`, on the unmodified code); only the
timings (keys ending in ``seconds``) are blanked before the comparison. An issue
that changes a number on purpose regenerates them and says so.

Byte for byte holds on the processor that wrote them (tests/data/golden_machine.txt):
another one's BLAS kernels round differently (an AMD EPYC against the files of an
earlier machine: C to 7e-14, the solver's residuals and asymmetries, which are
round-off themselves, by up to 30 %). There the text, the integers and the physics
(every number outside :data:`ROUND_OFF`) must still agree, the numbers to 1e-9 of their
row's largest, and the test says which comparison it made.
"""
import json
import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from helpers import ROOT, run_cli  # noqa: E402

DATA = os.path.join(ROOT, "tests", "data")
MACHINE = os.path.join(DATA, "golden_machine.txt")
#: Keys whose numbers are round-off or the solver's own error (not compared across machines).
ROUND_OFF = ("asymmetry", "residual", "correction", "love_weber_difference", "diagnostics",
             "energy_gap", "eigen", "condition")

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


def machine():
    """This processor, as the golden files name the one that wrote them: model and SIMD."""
    with open("/proc/cpuinfo") as f:
        info = f.read()
    model = next((line.split(":", 1)[1].strip() for line in info.splitlines()
                  if line.startswith("model name")), "unknown")
    flags = set(next((line.split(":", 1)[1].split() for line in info.splitlines()
                      if line.startswith("flags")), []))
    return " ".join([model] + [f for f in ("avx512f", "avx2") if f in flags])


def same_physics(expected, got, path=""):
    """Paths where ``got`` differs from ``expected`` beyond round-off (list of str)."""
    if any(key in path.rsplit("/", 1)[-1] for key in ROUND_OFF):
        return []
    if isinstance(expected, dict):
        if expected.keys() != got.keys():
            return [f"{path}: keys {sorted(expected)} != {sorted(got)}"]
        return [d for k in expected for d in same_physics(expected[k], got[k], f"{path}/{k}")]
    if isinstance(expected, list):
        if not isinstance(got, list) or len(expected) != len(got):
            return [f"{path}: {expected!r} != {got!r}"]
        if expected and all(isinstance(v, float) for v in expected + got):
            scale = max(abs(v) for v in expected + got)
            return [] if all(abs(a - b) <= 1e-9 * scale for a, b in zip(expected, got)) else [
                f"{path}: {expected} != {got}"]
        return [d for i, (a, b) in enumerate(zip(expected, got))
                for d in same_physics(a, b, f"{path}[{i}]")]
    if isinstance(expected, float) and isinstance(got, float):
        return [] if abs(expected - got) <= 1e-9 * max(abs(expected), abs(got)) else [
            f"{path}: {expected!r} != {got!r}"]
    return [] if expected == got else [f"{path}: {expected!r} != {got!r}"]


def test_same_physics_catches_a_change():
    """The cross-machine comparison fails on a changed modulus, a key or a string."""
    a = {"properties": {"Ex": 1.0e11}, "C": [[1.0, 2.0]], "bc": "kubc",
         "solver": {"residuals": [1e-9]}}
    assert same_physics(a, json.loads(json.dumps(a))) == []
    assert same_physics(a, {**a, "solver": {"residuals": [3e-9]}}) == []
    assert same_physics(a, {**a, "properties": {"Ex": 1.0e11 * (1 + 1e-7)}})
    assert same_physics(a, {**a, "C": [[1.0, 2.0 + 1e-6]]})
    assert same_physics(a, {**a, "bc": "subc"})
    assert same_physics(a, {k: v for k, v in a.items() if k != "bc"})


@pytest.mark.mpi
@pytest.mark.parametrize("name", sorted(RUNS))
def test_same_json_as_before(name, tmp_path):
    with open(os.path.join(DATA, f"golden_result_{name}.json")) as f:
        expected = f.read()
    got = run(name, str(tmp_path))
    with open(MACHINE) as f:
        writer = f.read().strip()
    if writer == machine():
        assert got == expected
    else:  # another processor's BLAS: the physics and the text, not the last bits
        assert same_physics(json.loads(expected), json.loads(got)) == [], (
            f"written on {writer!r}, compared on {machine()!r}")


if __name__ == "__main__" and sys.argv[1:] == ["--regenerate"]:
    import tempfile
    for name in RUNS:
        with tempfile.TemporaryDirectory() as tmp:
            text = run(name, tmp)
        with open(os.path.join(DATA, f"golden_result_{name}.json"), "w") as f:
            f.write(text)
        print("wrote", f"golden_result_{name}.json")
    with open(MACHINE, "w") as f:
        f.write(machine() + "\n")

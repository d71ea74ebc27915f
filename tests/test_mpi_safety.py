"""Issue 18, item 1: different inputs on different ranks are one error on every rank, no hang.

The issue's command: under `mpirun -n 2`, each rank passes its own bed
(``generate_bed(..., seed=rank)``) to homogenize_bed, which mixed the two
beds into one number (Ex = 4.85e11; seed 0 alone: 5.38e11); NaN on one rank
or one particle fewer hung. One mpirun runs every variant in turn.
"""
import json
import subprocess
import sys
import time

import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, cubic_lattice, run_cli

from amfe.errors import AmfeError
from amfe.solvers.consistency import agree_across_ranks, digest

SCRIPT = r'''
import json, sys
import numpy as np
from mpi4py import MPI
import amfe
from amfe.errors import AmfeError
from amfe.model.bed import Bed
sys.path.insert(0, "tests")   # run from the repository's root
from helpers import homogenize_arrays

rank = MPI.COMM_WORLD.rank
size = (0.15e-3, 0.15e-3, 0.08e-3)
bed = amfe.generate_bed(size=size, seed=0)
c, r = bed.centers.copy(), bed.radii.copy()
own = amfe.generate_bed(size=size, seed=rank)   # the issue's command
c_nan = c.copy()
if rank == 1:
    c_nan[3, 1] = np.nan
variants = {
    "seed": lambda: homogenize_arrays(own.centers, own.radii),
    "nan": lambda: homogenize_arrays(c_nan, r),
    "fewer": lambda: homogenize_arrays(c[:len(c) - rank], r[:len(r) - rank]),
    "material": lambda: homogenize_arrays(c, r, amfe.Material(E=210e9 - rank)),
    "rtol": lambda: homogenize_arrays(c, r, rtol=1e-8 * (1 + rank)),
    "partial_attrs": lambda: amfe.homogenize(Bed(c, r, {"material_E": 70e9} if rank else {})),
    "same_bad": lambda: homogenize_arrays(c * np.nan, r),
    "same": lambda: homogenize_arrays(c, r),
}
with open(f"{sys.argv[1]}.{rank}", "w") as log:   # one file per rank: no interleaving
    for name, run in variants.items():
        try:
            res = run()
            out = {"ok": res["properties"]["Ex"] if isinstance(res, dict) else res.Ex}
        except AmfeError as exc:
            out = {"error": str(exc)}
        log.write(json.dumps({"variant": name, "rank": rank, **out}) + "\n")
'''


@pytest.mark.mpi
def test_rank_divergent_inputs_are_one_error_on_every_rank(tmp_path):
    script = tmp_path / "divergent.py"
    script.write_text(SCRIPT)
    t0 = time.perf_counter()
    proc = subprocess.run(["mpirun", "-n", "2", sys.executable, str(script), str(tmp_path / "out")],
                          capture_output=True, text=True, env=MPI_ENV, cwd=ROOT, timeout=60)
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    seen = {}
    lines = (tmp_path / "out.0").read_text().splitlines() + \
        (tmp_path / "out.1").read_text().splitlines()
    for line in lines:
        d = json.loads(line)
        seen.setdefault(d.pop("variant"), {})[d.pop("rank")] = d
    assert len(seen) == 8 and all(len(v) == 2 for v in seen.values())
    for name in ("seed", "nan", "fewer", "material", "rtol", "partial_attrs"):
        a, b = seen[name][0], seen[name][1]
        assert "error" in a and a == b, name            # the same message on both ranks
        assert "different inputs" in a["error"], name
    assert "centers (same shape (168, 3)" in seen["seed"][0]["error"]
    assert "shapes rank 0: (168, 3), rank 1: (167, 3)" in seen["fewer"][0]["error"]
    assert "material" in seen["material"][0]["error"] and "options" in seen["rtol"][0]["error"]
    assert "rank 1 refused its input: the bed file's material is incomplete" in \
        seen["partial_attrs"][0]["error"]
    # the same bad input everywhere: its own message, on both ranks
    assert seen["same_bad"][0] == seen["same_bad"][1]
    assert "non-finite centres" in seen["same_bad"][0]["error"]
    # V: the spheres' box (arrays carry no recorded size; 5.3816e11 with the hull volume)
    assert seen["same"][0]["ok"] == seen["same"][1]["ok"] == pytest.approx(2.46636e11, rel=1e-4)
    assert wall < 10, f"{wall:.1f} s"


@pytest.mark.mpi
def test_unconverged_solve_under_mpirun_stops_every_rank(tmp_path):
    from amfe.io.bedfile import write_bed
    from amfe.model.bed import generate_bed
    bed = tmp_path / "bed.h5"
    write_bed(bed, generate_bed(size=(0.15e-3, 0.15e-3, 0.08e-3), seed=0))
    t0 = time.perf_counter()
    proc = run_cli(["homogenize", str(bed), "-o", str(tmp_path / "r.json"), "--quiet",
                    "-ksp_atol", "1e3", "-ksp_rtoll", "1"], ranks=2, timeout=60)
    assert time.perf_counter() - t0 < 10
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("amfe homogenize: error:") == 1
    assert "CONVERGED_ATOL after 0 iterations" in proc.stderr
    assert not (tmp_path / "r.json").exists()


def test_digest_sees_dtype_shape_and_every_bit():
    x, _ = cubic_lattice(3)
    assert digest(x) == digest(x.copy())
    assert digest(x) != digest(x.astype(np.float32).astype(np.float64) + 0 * x[0, 0] + 1e-300)
    assert digest(x) != digest(x.reshape(-1))
    assert digest(x) != digest(x.astype(np.float32))
    y = x.copy()
    y[-1, -1] = np.nextafter(y[-1, -1], np.inf)
    assert digest(x) != digest(y)
    assert digest([[1, 2], [3]]) == digest([[1, 2], [3]])   # ragged: hashed by repr


def test_agree_on_one_process_raises_the_error_or_returns_the_host():
    hosts = agree_across_ranks(None, {"a": np.arange(3)})
    assert len(hosts) == 1 and hosts[0][1] > 0
    with pytest.raises(AmfeError, match="bad"):
        agree_across_ranks(None, {"a": 1}, AmfeError("bad"))


API_SCRIPT = r'''
import json, sys
import numpy as np
from mpi4py import MPI
import amfe
from amfe.errors import AmfeError

rank = MPI.COMM_WORLD.rank
bed = amfe.generate_bed(size=(0.15e-3, 0.15e-3, 0.08e-3), seed=0)
path = sys.argv[1] + ".h5"
if rank == 0:
    amfe.write_bed(path, bed)
MPI.COMM_WORLD.barrier()
variants = {   # only rank 0 differs
    "max_memory": lambda: amfe.homogenize(bed, max_memory=1000 if rank == 0 else None),
    "path_or_bed": lambda: amfe.homogenize(path if rank == 0 else bed),
    "same": lambda: amfe.homogenize(path),
}
with open(f"{sys.argv[1]}.{rank}", "w") as log:
    for name, run in variants.items():
        try:
            out = {"ok": run().Ex}
        except AmfeError as exc:
            out = {"error": str(exc)}
        log.write(json.dumps({"variant": name, **out}) + "\n")
# Both logs are closed before rank 0 may die: its abort would otherwise kill rank 1 with
# its last lines still in the file buffer (seen under load: rank 1's log empty).
MPI.COMM_WORLD.barrier()
if sys.argv[2] == "nan" and rank == 0:   # an uncaught error in the user's script, rank 0 only
    amfe.Bed(np.full((3, 3), np.nan), np.ones(3))
amfe.homogenize(bed)
'''


@pytest.mark.mpi
@pytest.mark.parametrize("end", ["ok", "nan"])
def test_api_arguments_that_differ_on_one_rank(tmp_path, end):
    """Issue 31, API under 2 ranks, only rank 0: passes max_memory (refused there only: the
    other rank waited in the next collective), passes a path where rank 1 passes a Bed
    (on_root's bcast met the input check's allgather: a TypeError), or builds amfe.Bed from NaN
    and dies of it (rank 1 waited in homogenize for ever). Now one error on every rank, and an
    uncaught exception on one rank ends the job."""
    script = tmp_path / "api.py"
    script.write_text(API_SCRIPT)
    out = tmp_path / "out"
    proc = subprocess.run(["mpirun", "-n", "2", sys.executable, str(script), str(out), end],
                          capture_output=True, text=True, env=MPI_ENV, cwd=ROOT, timeout=60)
    logs = [[json.loads(line) for line in (tmp_path / f"out.{r}").read_text().splitlines()]
            for r in (0, 1)]
    assert logs[0] == logs[1] and len(logs[0]) == 3   # the same outcome on both ranks
    got = {d["variant"]: d for d in logs[0]}
    assert got["max_memory"]["error"] == ("max_memory differs across ranks: rank 0 passes "
                                          "1000, rank 1 None; every rank must pass the same")
    assert got["path_or_bed"]["error"].startswith("bed differs across ranks: rank 0 passes '")
    # V: the bed file's recorded size (label rule 2; 5.3816e11 with rule 1's hull volume)
    assert got["same"]["ok"] == pytest.approx(2.59077e11, rel=1e-4)
    if end == "ok":
        assert proc.returncode == 0, proc.stderr
    else:
        assert proc.returncode == 1 and "non-finite centres" in proc.stderr

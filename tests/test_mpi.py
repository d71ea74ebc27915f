"""`amfe homogenize` under mpirun: rank-count invariance, PETSc options, VTU, errors."""
import json
import os

import numpy as np
import pytest
from helpers import run_cli

from amfe.io.bedfile import write_bed
from amfe.io.result_meta import HEADER_KEYS
from amfe.io.vtu import read_case
from amfe.model.bed import generate_bed

pytestmark = pytest.mark.mpi

RESULT_KEYS = {"properties", "C", "S", "volume", "volume_box", "density", "n_particles",
               "n_removed", "n_bonds", "bc",
               "ranks", "solver", "schema_version", "material", "springs", "warnings",
               "removed"} | set(HEADER_KEYS)
PROPERTY_KEYS = {"Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy"}


@pytest.fixture(scope="module")
def bed_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("bed") / "bed.h5"
    write_bed(path, generate_bed(size=(120e-6, 100e-6, 60e-6), seed=11))
    return str(path)


@pytest.fixture(scope="module")
def results(bed_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    res = {}
    for ranks in (1, 2, 3):
        path = out / f"r{ranks}.json"
        proc = run_cli(["homogenize", bed_file, "-o", str(path), "--rtol", "1e-12"], ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        res[ranks] = json.loads(path.read_text())
    return res


def test_same_constants_on_1_2_3_ranks(results):
    C1 = np.array(results[1]["C"])
    for ranks in (2, 3):
        C = np.array(results[ranks]["C"])
        assert np.abs(C - C1).max() <= 1e-9 * np.abs(C1).max()
        assert results[ranks]["ranks"] == ranks


def test_result_json_layout(results):
    r = results[2]
    assert set(r) == RESULT_KEYS
    assert set(r["properties"]) == PROPERTY_KEYS
    assert np.array(r["C"]).shape == (6, 6) and np.array(r["S"]).shape == (6, 6)
    assert np.allclose(np.array(r["C"]) @ np.array(r["S"]), np.eye(6), atol=1e-10)
    assert r["bc"] == "kubc"
    s = r["solver"]
    assert s["ksp_type"] == "cg" and s["pc_type"] == "gamg" and len(s["iterations"]) == 6
    assert all(0 < it <= 30 for it in s["iterations"])
    assert max(s["residuals"]) < 1e-10  # true residuals, not just preconditioned


def test_petsc_options_reach_petsc(bed_file, results, tmp_path):
    out = tmp_path / "hypre.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "--rtol", "1e-10",
                    "-pc_type", "hypre", "-ksp_monitor", "-log_view"], ranks=2)
    assert proc.returncode == 0, proc.stderr
    assert "KSP Residual norm" in proc.stdout
    assert "Performance Summary" in proc.stdout  # -log_view
    r = json.loads(out.read_text())
    assert r["solver"]["pc_type"] == "hypre"
    C, C1 = np.array(r["C"]), np.array(results[1]["C"])
    assert np.abs(C - C1).max() <= 1e-7 * np.abs(C1).max()


def test_vtu_written_once_and_complete_under_two_ranks(bed_file, tmp_path):
    vtu = tmp_path / "vtu"
    proc = run_cli(["homogenize", bed_file, "--vtu", str(vtu)], ranks=2)
    assert proc.returncode == 0, proc.stderr
    files = sorted(os.listdir(vtu))
    assert files == sorted(["cases.json", "cases.pvd"] + [f"case_{n}.vtu" for n in
                                            ["xx", "yy", "zz", "yz", "xz", "xy"]])
    assert "Ex" in proc.stdout
    m = read_case(vtu / "case_xx.vtu")
    for name in ("displacement_m", "rotation_rad", "radius_m", "particle_id"):
        assert name in m["point_data"]
    for name in ("axial_force_N", "shear_force_N", "torsion_Nm", "bending_moment_Nm"):
        assert name in m["cell_data"]
    # case xx, unit strain: boundary particles move by x - x_c along x
    u = m["point_data"]["displacement_m"]
    x = m["points"]
    xc = (x.max(axis=0) + x.min(axis=0)) / 2
    edge = np.isclose(x[:, 0], x[:, 0].min())
    assert np.allclose(u[edge, 0], x[edge, 0] - xc[0], rtol=1e-9)


def test_divergence_stops_every_rank_with_one_clear_error(bed_file, tmp_path):
    out = tmp_path / "never.json"
    proc = run_cli(["homogenize", bed_file, "-o", str(out), "-ksp_max_it", "1"], ranks=2,
                   timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.count("did not converge") == 1, proc.stderr
    assert "DIVERGED_MAX_IT" in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()


def test_missing_bed_is_a_clear_error(tmp_path):
    proc = run_cli(["homogenize", str(tmp_path / "nope.h5")], ranks=2, timeout=120)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "nope.h5" in proc.stderr


def test_groups_of_a_split_communicator_solve_their_own_beds(tmp_path):
    """COMM_WORLD split in two groups of one rank: each solves a different bed alone."""
    script = tmp_path / "split.py"
    script.write_text(
        "import json, sys\n"
        "from mpi4py import MPI\n"
        "from amfe.model.bed import generate_bed\n"
        "from amfe.model.options import SolveOptions\n"
        "from amfe.solvers.driver import homogenize_bed\n"
        "w = MPI.COMM_WORLD\n"
        "g = w.Split(color=w.rank, key=0)\n"
        "bed = generate_bed(size=(100e-6, 100e-6, 60e-6), seed=20 + w.rank)\n"
        "options = SolveOptions(rtol=1e-12, solver='gamg')\n"
        "r = homogenize_bed(bed, options, g)\n"
        "alone = homogenize_bed(bed, options, MPI.COMM_SELF)\n"
        "out = w.gather((r.ranks, r.Ex, alone.Ex), root=0)\n"
        "if w.rank == 0: print(json.dumps(out))\n")
    import subprocess
    import sys

    from helpers import MPI_ENV, ROOT
    proc = subprocess.run(["mpirun", "-n", "2", sys.executable, str(script)], capture_output=True,
                          text=True, cwd=ROOT, env=MPI_ENV, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert [o[0] for o in out] == [1, 1]
    assert out[0][1] != out[1][1]  # different beds
    for ranks, ex, ex_alone in out:
        assert ex == pytest.approx(ex_alone, rel=1e-10)

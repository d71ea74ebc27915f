"""The Python face: homogenize() on a path, a Bed and arrays; Result; fields; doctests; examples."""
import doctest
import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, run_cli

import amfe
from amfe.io.result import SCHEMA_VERSION, Result
from amfe.io.vtu import read_case
from amfe.vocab import CASE_NAMES, CONSTANT_NAMES

SIZE = (0.1e-3, 0.1e-3, 0.06e-3)


@pytest.fixture(scope="module")
def bed_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("api") / "bed.h5"
    amfe.write_bed(path, amfe.generate_bed(size=SIZE, seed=4))
    return path


@pytest.fixture(scope="module")
def with_fields(bed_path):
    return amfe.homogenize(bed_path, rtol=1e-10, fields=True)


def test_path_bed_and_cli_give_the_same_answer(bed_path, with_fields, tmp_path):
    from_bed = amfe.homogenize(amfe.read_bed(bed_path), rtol=1e-10)
    bed = amfe.read_bed(bed_path)
    from_arrays = amfe.homogenize((bed.centers, bed.radii), rtol=1e-10)
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(bed_path), "-o", str(out), "--rtol", "1e-10", "--quiet"])
    assert proc.returncode == 0, proc.stderr
    cli = json.loads(out.read_text())
    np.testing.assert_array_equal(from_bed.C, with_fields.C)
    assert from_bed.properties == with_fields.properties
    # arrays carry no recorded size: V is the spheres' box, the kept set the same, so C V
    # (the reaction moments) agrees (docs/model.md, section 5)
    assert from_arrays.volume < from_bed.volume == pytest.approx(np.prod(SIZE), rel=1e-12)
    np.testing.assert_allclose(from_arrays.C * from_arrays.volume,
                               with_fields.C * with_fields.volume, rtol=1e-12, atol=0)
    np.testing.assert_allclose(np.array(cli["C"]), with_fields.C, rtol=1e-12, atol=0)
    for k in CONSTANT_NAMES:
        assert cli["properties"][k] == pytest.approx(with_fields.properties[k], rel=1e-12)
    assert cli["schema_version"] == SCHEMA_VERSION


def test_result_dataclass(with_fields, tmp_path):
    r = with_fields
    assert isinstance(r, Result) and r.C.shape == (6, 6) and r.S.shape == (6, 6)
    np.testing.assert_allclose(r.S @ r.C, np.eye(6), atol=1e-9)
    assert r.Ex == r.properties["Ex"] == pytest.approx(1 / r.S[0, 0])
    assert r.nu_xy == pytest.approx(-r.S[1, 0] / r.S[0, 0])   # nu_ij = -S_ji / S_ii
    assert "Ex" in dir(r) and "GPa" in repr(r) and "kubc" in repr(r)
    with pytest.raises(AttributeError):
        r.no_such_constant
    r.to_json(tmp_path / "r.json")
    d = json.loads((tmp_path / "r.json").read_text())
    assert d == json.loads(json.dumps(r.to_dict()))
    back = Result.from_dict(d)
    np.testing.assert_array_equal(back.C, r.C)


def test_fields_equal_what_the_vtu_holds(with_fields, bed_path, tmp_path):
    r = with_fields
    f = r.fields
    n, m = r.n_particles - r.n_removed, r.n_bonds
    assert f.displacement.shape == (6, n, 3) and f.rotation.shape == (6, n, 3)
    assert f.axial_force.shape == (6, m) and f.bonds.shape == (m, 2)
    bed = amfe.read_bed(bed_path)
    np.testing.assert_array_equal(f.centers, bed.centers[f.particle_id])
    # The files written from the API and those the CLI writes hold the same arrays.
    paths = r.write_vtu(tmp_path / "api")
    proc = run_cli(["homogenize", str(bed_path), "--vtu", str(tmp_path / "cli"),
                    "--rtol", "1e-10", "--quiet"])
    assert proc.returncode == 0, proc.stderr
    for k, name in enumerate(CASE_NAMES):
        mesh = read_case(paths[k])
        cli = read_case(tmp_path / "cli" / f"case_{name}.vtu")
        np.testing.assert_array_equal(mesh["points"], f.centers)
        np.testing.assert_array_equal(mesh["point_data"]["displacement_m"], f.displacement[k])
        np.testing.assert_array_equal(mesh["point_data"]["rotation_rad"], f.rotation[k])
        np.testing.assert_array_equal(mesh["cell_data"]["axial_force_N"], f.axial_force[k])
        np.testing.assert_allclose(cli["point_data"]["displacement_m"], f.displacement[k],
                                   rtol=1e-12, atol=1e-12 * abs(f.displacement[k]).max())
    # The affine part: the mean displacement gradient of case xx is e_x e_x.
    u, x = f.displacement[0], f.centers - f.centers.mean(0)
    H = np.linalg.lstsq(x, u - u.mean(0), rcond=None)[0].T
    assert H[0, 0] == pytest.approx(1.0, abs=0.1) and abs(H[1, 1]) < 0.5


def test_bad_bed_argument_is_a_clear_error():
    with pytest.raises(amfe.AmfeError, match="bed must be"):
        amfe.homogenize(42)
    with pytest.raises(amfe.AmfeError):
        amfe.homogenize("/nonexistent/bed.h5")


@pytest.mark.parametrize("module", ["amfe", "amfe.api", "amfe.io.result", "amfe.vocab"])
def test_doctests(module):
    mod = __import__(module, fromlist=["_"])
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0


def test_help_lists_the_face():
    import pydoc
    text = pydoc.render_doc(amfe, renderer=pydoc.plaintext)
    for name in ("homogenize", "Result", "Surrogate", "read_bed", "generate_bed"):
        assert name in text


def _run(cmd, **kw):
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300, **kw)


def test_example_1_bed_to_constants(tmp_path):
    proc = _run([sys.executable, "examples/01_bed_to_constants.py", str(tmp_path), "--tiny"])
    assert proc.returncode == 0, proc.stderr
    d = json.loads((tmp_path / "result.json").read_text())
    ex = float(proc.stdout.split("4. Ex = ")[1].split()[0])
    assert ex == pytest.approx(d["properties"]["Ex"] / 1e9, abs=0.05)
    assert (tmp_path / "vtu" / "cases.pvd").is_file()


def test_example_2_surrogate():
    proc = _run([sys.executable, "examples/02_surrogate.py"])
    assert proc.returncode == 0, proc.stderr
    errors = [float(line.split("error")[1].split()[0]) for line in proc.stdout.splitlines()
              if line.startswith("3.")]
    # a smoke test of the whole path; the accuracy is measured in docs/surrogate.md
    assert len(errors) == 6 and max(abs(e) for e in errors) < 50


@pytest.mark.mpi
def test_example_3_mpi_matches_one_rank(bed_path, with_fields):
    proc = _run(["mpirun", "-n", "2", sys.executable, "examples/03_mpi.py", str(bed_path)],
                env=MPI_ENV)
    assert proc.returncode == 0, proc.stderr
    ex = float(proc.stdout.split("Ex = ")[1].split()[0])
    assert ex == pytest.approx(with_fields.Ex / 1e9, abs=1e-4)


def test_json_to_stdout_matches_the_file(bed_path, tmp_path):
    out = tmp_path / "r.json"
    to_file = run_cli(["homogenize", str(bed_path), "-o", str(out), "--quiet"])
    to_stdout = run_cli(["homogenize", str(bed_path), "-o", "-", "--quiet"])
    assert to_file.returncode == 0 and to_stdout.returncode == 0, to_stdout.stderr
    piped, saved = json.loads(to_stdout.stdout), json.loads(out.read_text())
    assert piped["C"] == saved["C"] and piped["properties"] == saved["properties"]
    assert "Ex" in to_stdout.stderr and not (tmp_path / "-").exists()

"""The ParaView files of `amfe homogenize --vtu`, read by VTK's reader and amfe's; `amfe view`."""
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, run_cli

import amfe
from amfe.io.pvd import case_fields
from amfe.io.vtu import read_case
from amfe.model.element import particle_resultants
from amfe.viz.pvrun import paraview_command, run_pvpython

CASES = ("xx", "yy", "zz", "yz", "xz", "xy")
POINT = {"particle_id", "radius_m", "boundary", "displacement_m", "rotation_rad"}
CELL = {"i", "j", "a_star", "force_i_N", "moment_i_Nm", "axial_force_N", "shear_force_N",
        "torsion_Nm", "bending_moment_Nm"}


@pytest.fixture(scope="module")
def beds(tmp_path_factory):
    """A bed, and a periodic one for --bc periodic."""
    tmp = tmp_path_factory.mktemp("view")
    amfe.write_bed(tmp / "bed.h5", amfe.generate_bed(size=(0.15e-3, 0.15e-3, 0.08e-3), seed=3))
    amfe.write_bed(tmp / "periodic.h5", amfe.generate_bed((100e-6, 100e-6, 100e-6), seed=6,
                                                          periodic=True))
    return tmp


def homogenize(beds, bc):
    """`amfe homogenize` at rtol 1e-12 with --vtu: (JSON result, output directory, bed)."""
    bed, out = beds / ("periodic.h5" if bc == "periodic" else "bed.h5"), beds / bc
    if not (out / "r.json").exists():
        out.mkdir(exist_ok=True)
        proc = run_cli(["homogenize", str(bed), "-o", str(out / "r.json"), "--vtu", str(out),
                        "--rtol", "1e-12", "--bc", bc, "--solver", "gamg", "--quiet"])
        assert proc.returncode == 0, proc.stderr
    return json.loads((out / "r.json").read_text()), out, bed


@pytest.fixture(scope="module", params=["kubc", "mixed", "subc", "periodic"])
def solved(request, beds):
    """Every boundary condition: the files must hold for every case of each."""
    return homogenize(beds, request.param)


@pytest.fixture(scope="module")
def kubc(beds):
    """One result for the tests of amfe view."""
    return homogenize(beds, "kubc")


def vtk_read(path):
    """Everything in a .vtu, through VTK's vtkXMLUnstructuredGridReader (field: cases.json)."""
    xml = pytest.importorskip("vtkmodules.vtkIOXML", reason="VTK's reader (ParaView's "
                              "python3-paraview or the vtk wheel) is not installed")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    reader = xml.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    assert reader.GetErrorCode() == 0
    out = reader.GetOutput()
    pd, cd = out.GetPointData(), out.GetCellData()
    types = [out.GetCellType(k) for k in range(out.GetNumberOfCells())]
    return {"n_points": out.GetNumberOfPoints(), "n_cells": out.GetNumberOfCells(),
            "n_lines": types.count(3), "points": vtk_to_numpy(out.GetPoints().GetData()),
            "lines": vtk_to_numpy(out.GetCells().GetConnectivityArray()).reshape(-1, 2),
            "point": {pd.GetArrayName(k): vtk_to_numpy(pd.GetArray(k))
                      for k in range(pd.GetNumberOfArrays())},
            "cell": {cd.GetArrayName(k): vtk_to_numpy(cd.GetArray(k))
                     for k in range(cd.GetNumberOfArrays())},
            "field": case_fields(path)}


def meshio_read(path):
    """The same through meshio (amfe.io.vtu.read_case: what the matplotlib fallback reads)."""
    d = read_case(path)
    return {"n_points": len(d["points"]), "n_cells": len(d["lines"]), "n_lines": len(d["lines"]),
            "points": d["points"], "lines": d["lines"], "point": d["point_data"],
            "cell": d["cell_data"], "field": d["field_data"]}


@pytest.fixture(params=["vtk", "meshio"])
def read(request):
    return {"vtk": vtk_read, "meshio": meshio_read}[request.param]


def test_every_file_reads_with_vtk_and_matches_the_json_counts(solved, read):
    result, out, _ = solved
    counts = result["counts"]
    files = result["vtk"]["files"]
    assert [os.path.basename(p) for p in files] == [f"case_{c}.vtu" for c in CASES]
    assert sorted(os.listdir(out)) == sorted([f"case_{c}.vtu" for c in CASES]
                                             + ["cases.json", "cases.pvd", "r.json"])
    for case, path in zip(CASES, files):
        d = read(path)
        kept = result["n_particles"] - result["n_removed"]
        assert d["n_points"] == counts["particles_kept"] == kept
        not_drawn = d["field"]["bonds_not_drawn"]           # periodic: across a face
        assert (not_drawn > 0) == (result["bc"] == "periodic")
        assert d["n_cells"] == d["n_lines"] == counts["bonds_kept"] - not_drawn
        assert counts["bonds_kept"] == result["n_bonds"]
        assert set(d["point"]) == POINT and set(d["cell"]) == CELL
        assert all(len(a) == d["n_points"] for a in d["point"].values())
        assert all(len(a) == d["n_lines"] for a in d["cell"].values())
        field = d["field"]
        assert field["case_name"] == case and field["bc"] == result["bc"]
        assert field["amfe_version"] == result["amfe_version"]
        if result["bc"] == "subc":                 # unit macro-stresses, of E
            sig = np.asarray(field["macro_stress_Pa"]).reshape(3, 3)
            voigt = sig[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]] / result["material"]["E"]
        else:
            eps = np.asarray(field["macro_strain"]).reshape(3, 3)
            voigt = eps[[0, 1, 2, 1, 0, 0], [0, 1, 2, 2, 2, 1]] * [1, 1, 1, 2, 2, 2]
        np.testing.assert_allclose(voigt, np.eye(6)[CASES.index(case)], rtol=0, atol=1e-12)
        pid = d["point"]["particle_id"]            # the cells' i, j are the lines' input ids
        np.testing.assert_array_equal(pid[d["lines"][:, 0]], d["cell"]["i"])
        np.testing.assert_array_equal(pid[d["lines"][:, 1]], d["cell"]["j"])


def test_particle_id_maps_each_point_to_its_bed_centre(solved, read):
    result, out, bed = solved
    b = amfe.read_bed(bed)
    for path in result["vtk"]["files"]:
        d = read(path)
        pid = d["point"]["particle_id"]
        assert np.all(np.diff(pid) > 0)            # input order
        # the points are the undeformed centres, bit for bit; displacements are separate
        np.testing.assert_array_equal(d["points"], b.centers[pid])
        np.testing.assert_array_equal(d["point"]["radius_m"], b.radii[pid])
    removed = np.setdiff1d(np.arange(b.n), pid)
    assert removed.size == result["n_removed"]


@pytest.mark.parametrize("k", range(6))
def test_bond_loads_balance_at_every_interior_particle(solved, k, read):
    """Free particles: the bond forces (and moments) sum to zero at rtol 1e-12."""
    result, _, _ = solved
    d = read(result["vtk"]["files"][k])
    x, cell = d["points"], d["cell"]
    index = {p: n for n, p in enumerate(d["point"]["particle_id"])}
    i = np.array([index[p] for p in cell["i"]])
    j = np.array([index[p] for p in cell["j"]])
    branch = x[j] - x[i]
    length = np.linalg.norm(branch, axis=1)
    e = branch / length[:, None]
    f, m = particle_resultants(len(x), i, j, e, length, cell["force_i_N"], cell["moment_i_Nm"])
    interior = d["point"]["boundary"] == 0
    assert 0 < interior.sum() < len(x)
    fscale = np.median(np.linalg.norm(cell["force_i_N"], axis=1))
    mscale = np.median(np.linalg.norm(cell["moment_i_Nm"], axis=1))
    assert np.abs(f[interior]).max() < 1e-8 * fscale
    assert np.abs(m[interior]).max() < 1e-8 * mscale
    assert np.abs(f[~interior]).max() > 1e-3 * fscale  # the reactions are not trivially zero
    np.testing.assert_allclose(np.einsum("ij,ij->i", cell["force_i_N"], e),
                               cell["axial_force_N"], atol=1e-10 * fscale)


def png_size(path):
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def bare_env(tmp_path, tools=()):
    """An environment without a display whose PATH holds Python and the given fake tools."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    for name, script in tools:
        p = bin_dir / name
        p.write_text("#!/bin/sh\n" + script + "\n")
        p.chmod(p.stat().st_mode | stat.S_IEXEC)
    env = {k: v for k, v in MPI_ENV.items() if k != "DISPLAY"}
    env["PATH"] = f"{bin_dir}:{os.path.dirname(sys.executable)}"
    return env


def view(args, env=None, cwd=None):
    return subprocess.run([sys.executable, "-m", "amfe.cli", "view", *args], capture_output=True,
                          text=True, cwd=cwd or ROOT, env=env or MPI_ENV, timeout=300)


def test_view_without_paraview_writes_a_png_of_the_expected_size(kubc, tmp_path):
    result, out, _ = kubc
    png = tmp_path / "png" / "view_xx_axial_force.png"
    proc = view([str(out), "-o", str(png.parent), "--case", "xx", "--size", "640x480"],
                env=bare_env(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert png_size(png) == (640, 480)
    assert os.listdir(png.parent) == [png.name]
    assert "matplotlib" in proc.stdout and f"wrote {png}" in proc.stdout
    warp = float(proc.stdout.split("warp factor ")[1].split()[0])
    d = vtk_read(result["vtk"]["files"][0])
    side = np.ptp(d["points"], axis=0).max()
    umax = np.linalg.norm(d["point"]["displacement_m"], axis=1).max()
    assert warp * umax == pytest.approx(0.05 * side, rel=1e-3)


def test_a_failing_pvpython_falls_back_or_fails_cleanly(kubc, tmp_path):
    _, out, _ = kubc
    env = bare_env(tmp_path, [("pvpython", "echo 'Error: broken' >&2; exit 1"),
                              ("xvfb-run", 'shift 3; exec "$@"')])   # -a -n N pvpython ...
    png = tmp_path / "auto" / "view_yz_torsion.png"
    proc = view([str(out), "-o", str(png.parent), "--case", "yz", "--color", "torsion",
                 "--size", "320x240"], env=env)
    assert proc.returncode == 0, proc.stderr
    assert "broken" in proc.stderr and "falling back to matplotlib" in proc.stdout
    assert png_size(png) == (320, 240)
    proc = view([str(out), "-o", str(tmp_path / "pv"), "--case", "yz", "--backend", "paraview"],
                env=env)
    assert proc.returncode == 2 and "pvpython could not render case yz" in proc.stderr
    assert os.listdir(tmp_path / "pv") == []       # no PNG, no temporary


def test_paraview_command_needs_a_display_or_xvfb(tmp_path):
    env = bare_env(tmp_path, [("pvpython", "exit 0")])
    assert paraview_command(env) is None
    assert paraview_command({**env, "DISPLAY": ":0"}) == [str(tmp_path / "bin" / "pvpython")]
    env = bare_env(tmp_path, [("xvfb-run", "exit 0")])
    assert paraview_command(env)[:2] == [str(tmp_path / "bin" / "xvfb-run"), "-a"]


@pytest.mark.skipif(paraview_command() is None, reason="ParaView's pvpython (and a display or "
                    "xvfb-run) is not installed: apt-get install paraview python3-paraview xvfb")
def test_view_with_paraview_writes_a_png_and_a_state(kubc, tmp_path):
    _, out, _ = kubc
    proc = view([str(out), "-o", str(tmp_path), "--case", "yz", "--color", "shear_force",
                 "--size", "400x300", "--backend", "paraview", "--state"])
    assert proc.returncode == 0, proc.stderr
    assert png_size(tmp_path / "view_yz_shear_force.png") == (400, 300)
    assert "shear_force_N" in (tmp_path / "view_yz_shear_force.pvsm").read_text()


PV_CHECK = """
import sys
from paraview.simple import LoadState, GetActiveView, PVDReader, SaveScreenshot
reader = PVDReader(FileName=sys.argv[1])
reader.UpdatePipeline()
print("times", [int(t) for t in reader.TimestepValues])
for t in reader.TimestepValues:
    reader.UpdatePipeline(t)
    info = reader.GetDataInformation()
    print("case", int(t), info.GetNumberOfPoints(), info.GetNumberOfCells(),
          sorted(reader.PointData.keys()), sorted(reader.CellData.keys()))
LoadState(sys.argv[2])
SaveScreenshot(sys.argv[3], GetActiveView(), ImageResolution=[320, 240])
"""


@pytest.mark.skipif(paraview_command() is None, reason="ParaView's pvpython (and a display or "
                    "xvfb-run) is not installed: apt-get install paraview python3-paraview xvfb")
def test_paraview_opens_the_collection_reads_every_array_and_the_state(kubc, tmp_path):
    """Debian's ParaView 5.11: cases.pvd with every array of every case; the script's view of
    it with no manual step; a saved state that loads again (docs/viewing.md)."""
    result, out, _ = kubc
    png, state = tmp_path / "pvd.png", tmp_path / "pvd.pvsm"
    cmd = paraview_command()
    # on an X server of its own, retried if Xvfb refuses (as amfe view runs it)
    proc = run_pvpython(cmd + [str(Path(amfe.__file__).parent / "viz" / "amfe_view_pv.py"),
                               str(out / "cases.pvd"), "--png", str(png), "--size", "400",
                               "300", "--state", str(state)])
    assert png_size(png) == (400, 300), proc.stdout + proc.stderr
    check = tmp_path / "check.py"
    check.write_text(PV_CHECK)
    proc = run_pvpython(cmd + [str(check), str(out / "cases.pvd"), str(state),
                               str(tmp_path / "state.png")])
    lines = proc.stdout.splitlines()
    assert "times [0, 1, 2, 3, 4, 5]" in lines, proc.stdout + proc.stderr
    n = result["counts"]
    for k in range(6):
        assert f"case {k} {n['particles_kept']} {n['bonds_kept']} {sorted(POINT)} " \
               f"{sorted(CELL)}" in lines
    assert png_size(tmp_path / "state.png") == (320, 240)


@pytest.mark.parametrize("argv, message", [
    (["--case", "qq"], "the result has cases xx, yy, zz, yz, xz, xy"),
    (["--color", "stress"], "choose one of axial_force"),
    (["--size", "big"], "WIDTHxHEIGHT"),
    (["--size", "1x1"], "16..8192"),
    (["--backend", "vtk"], "invalid choice: 'vtk'"),
    (["--state", "--backend", "matplotlib"], "--state saves a ParaView state"),
])
def test_bad_values_exit_2_and_write_nothing(kubc, tmp_path, argv, message):
    _, out, _ = kubc
    before = sorted(os.listdir(out))
    proc = view([str(out), "-o", str(tmp_path / "none")] + argv)
    assert proc.returncode == 2 and message in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "none").exists() and sorted(os.listdir(out)) == before


def test_bad_targets_and_outputs_exit_2_and_write_nothing(kubc, tmp_path):
    _, out, _ = kubc
    (tmp_path / "a_file").write_text("x")
    old = tmp_path / "old"                     # amfe 0.1: .vtu files, no cases.json
    old.mkdir()
    (old / "cases.pvd").write_text('<VTKFile type="Collection"><Collection><DataSet '
                                   'timestep="0" file="case_0_xx.vtu" name="xx"/></Collection>'
                                   '</VTKFile>')
    v02 = tmp_path / "v02"                     # amfe 0.2: .vtp files
    v02.mkdir()
    (v02 / "cases.pvd").write_text((out / "cases.pvd").read_text().replace(".vtu", ".vtp"))
    v02_bare = tmp_path / "v02_bare"           # its case files without the collection
    v02_bare.mkdir()
    (v02_bare / "case_xx.vtp").write_text("<VTKFile/>")
    rewrite = "write the result again as .vtu: 'amfe homogenize BED.h5 --vtu DIR'"
    cases = [([str(tmp_path / "missing")], "no such file or directory"),
             ([str(tmp_path)], "holds no cases.pvd; write the files with 'amfe homogenize"),
             ([str(old)], "files of an older amfe (no cases.json), which amfe 0.3.0 does not "
                          "read; " + rewrite),
             ([str(v02)], ".vtp files of amfe 0.2, which amfe 0.3.0 does not read; " + rewrite),
             ([str(v02_bare)], ".vtp files of amfe 0.2"),
             ([str(v02_bare / "case_xx.vtp")], "a .vtp file of amfe 0.2"),
             ([str(out), "-o", str(tmp_path / "a_file")], "exists and is not a directory")]
    for argv, message in cases:
        before = sorted(os.listdir(tmp_path))
        proc = view(argv + ["--backend", "matplotlib"])
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr
        assert sorted(os.listdir(tmp_path)) == before
    proc = view([str(out), "-o", str(tmp_path / "none"), "--backend", "paraview"],
                env=bare_env(tmp_path))
    assert proc.returncode == 2 and "apt-get install paraview" in proc.stderr
    assert not (tmp_path / "none").exists()
    assert shutil.which("amfe", path=os.path.dirname(sys.executable))  # the console script

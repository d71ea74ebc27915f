"""ParaView output (amfe.io.vtu, amfe.io.pvd) and the bond end loads it holds."""
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.io import pvd, vtu
from amfe.io.fields import Fields
from amfe.model.element import bond_end_loads, element_matrices, particle_resultants


def random_bonds(m, seed=0):
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(m, 3))
    e /= np.linalg.norm(e, axis=1)[:, None]
    d_i, d_j = rng.uniform(0.5, 1.0, m), rng.uniform(0.5, 1.0, m)
    springs = [rng.uniform(0.5, 2.0, m) for _ in range(4)]
    return e, d_i, d_j, springs, rng.normal(size=(m, 6)), rng.normal(size=(m, 6))


def test_end_loads_are_minus_the_energy_gradient():
    # Independent: the 12x12 element matrix K gives the loads on both ends as -K [u_i; u_j].
    e, d_i, d_j, springs, u_i, u_j = random_bonds(50)
    loads = bond_end_loads(e, d_i, d_j, springs, u_i, u_j)
    K = element_matrices(e, d_i, d_j, *springs)
    g = -np.einsum("mab,mb->ma", K, np.concatenate([u_i, u_j], axis=1))
    np.testing.assert_allclose(loads["force_i"], g[:, :3], atol=1e-12)
    np.testing.assert_allclose(loads["moment_i"], g[:, 3:6], atol=1e-12)
    # j's end: -f_i and L e x f_i - m_i (the end_convention the files state)
    L = (d_i + d_j)[:, None]
    np.testing.assert_allclose(g[:, 6:9], -loads["force_i"], atol=1e-12)
    np.testing.assert_allclose(g[:, 9:], L * np.cross(e, loads["force_i"]) - loads["moment_i"],
                               atol=1e-12)
    # the split: axial = f.e, shear = |f - (f.e) e|; torsion and bending from the couple
    f = loads["force_i"]
    axial = np.einsum("ij,ij->i", f, e)
    np.testing.assert_allclose(loads["axial"], axial, atol=1e-12)
    np.testing.assert_allclose(loads["shear"], np.linalg.norm(f - axial[:, None] * e, axis=1),
                               atol=1e-12)
    couple = loads["moment_i"] - d_i[:, None] * np.cross(e, f)
    tors = np.einsum("ij,ij->i", couple, e)
    np.testing.assert_allclose(loads["torsion"], tors, atol=1e-12)
    np.testing.assert_allclose(loads["bending"], np.linalg.norm(couple - tors[:, None] * e,
                                                                axis=1), atol=1e-12)


def test_rigid_motion_loads_nothing_and_resultants_sum():
    e, d_i, d_j, springs, _, _ = random_bonds(20, seed=1)
    # particle i at 0, j at L e: a rigid rotation w and translation t
    w, t = np.array([0.3, -0.2, 0.5]), np.array([1.0, 2.0, -1.0])
    x_j = (d_i + d_j)[:, None] * e
    u_i = np.tile(np.r_[t, w], (20, 1))
    u_j = np.concatenate([t + np.cross(w, x_j), np.tile(w, (20, 1))], axis=1)
    loads = bond_end_loads(e, d_i, d_j, springs, u_i, u_j)
    assert np.abs(loads["force_i"]).max() < 1e-12 and np.abs(loads["moment_i"]).max() < 1e-12
    # two particles, one bond: the resultants are the two ends' loads
    f, m = particle_resultants(2, np.array([0]), np.array([1]), e[:1], [2.0],
                               np.array([[1.0, 0, 0]]), np.array([[0, 0, 1.0]]))
    np.testing.assert_allclose(f, [[1, 0, 0], [-1, 0, 0]])
    np.testing.assert_allclose(m[0], [0, 0, 1])
    np.testing.assert_allclose(m[1], 2.0 * np.cross(e[0], [1.0, 0, 0]) - [0, 0, 1])


def tiny_fields(k=2, nan=False, names=None):
    """Three particles, two bonds, ``k`` cases, values that differ everywhere."""
    n, m = 3, 2
    x = np.array([[0.0, 0, 0], [1e-5, 0, 0], [0, 2e-5, 0]])
    val = np.arange(1.0, 1 + k * m).reshape(k, m)
    if nan:
        val[-1, -1] = np.nan
    return Fields(particle_id=np.array([4, 7, 9]), centers=x, radii=np.array([6e-6, 7e-6, 8e-6]),
                  bonds=np.array([[0, 1], [0, 2]]), a_star=np.array([0.5, 0.6]),
                  boundary=np.array([[1, 0, 0]] * k, bool),
                  macro_strain=np.array([np.diag([1.0, 0, 0])] * k),
                  displacement=np.arange(k * n * 3, dtype=float).reshape(k, n, 3) * 1e-7,
                  rotation=np.ones((k, n, 3)), force=np.ones((k, m, 3)) * 2,
                  moment=np.ones((k, m, 3)) * 3, axial_force=val, shear_force=val + 1,
                  torsion=-val, bending_moment=val * 2,
                  case_names=tuple(names or ["xx", "yy"][:k]))


def test_write_and_read_back(tmp_path):
    f = tiny_fields()
    paths = vtu.write_fields_vtu(tmp_path / "new" / "sub", f, field_data={"note": "hi"})
    assert [os.path.basename(p) for p in paths] == ["case_xx.vtu", "case_yy.vtu", "cases.pvd"]
    assert sorted(os.listdir(tmp_path / "new" / "sub")) == ["case_xx.vtu", "case_yy.vtu",
                                                          "cases.json", "cases.pvd"]
    assert pvd.read_collection(paths[-1]) == [("xx", paths[0]), ("yy", paths[1])]
    for k in range(2):
        d = vtu.read_case(paths[k])
        np.testing.assert_array_equal(d["points"], f.centers)
        np.testing.assert_array_equal(d["lines"], f.bonds)
        assert set(d["point_data"]) == set(vtu.POINT_ARRAYS)
        assert set(d["cell_data"]) == set(vtu.CELL_ARRAYS)
        np.testing.assert_array_equal(d["point_data"]["particle_id"], [4, 7, 9])
        np.testing.assert_array_equal(d["cell_data"]["i"], [4, 4])
        np.testing.assert_array_equal(d["cell_data"]["j"], [7, 9])
        np.testing.assert_array_equal(d["cell_data"]["torsion_Nm"], f.torsion[k])
        np.testing.assert_array_equal(d["point_data"]["displacement_m"], f.displacement[k])
        np.testing.assert_array_equal(d["point_data"]["boundary"], f.boundary[k])
        fd = d["field_data"]                          # from cases.json
        assert fd["case_name"] == ("xx", "yy")[k] and fd["note"] == "hi"
        assert fd["case_label"] == f"{('xx', 'yy')[k]}: eps_xx = 1"
        assert fd["macro_strain_voigt"] == [1, 0, 0, 0, 0, 0]
        assert fd["macro_strain"] == np.diag([1.0, 0, 0]).ravel().tolist()
        # the largest displacement, times the warp factor, is 5 % of the box's largest side
        u = np.linalg.norm(f.displacement[k], axis=1).max()
        assert fd["warp_factor"] * u == pytest.approx(0.05 * 2e-5)
        assert fd["units"]["axial_force_N"] == "N" and fd["bc"] == "kubc"


def test_a_new_set_removes_the_old_one_and_bad_input_touches_nothing(tmp_path):
    vtu.write_fields_vtu(tmp_path, tiny_fields(k=2))      # the earlier set: xx and yy
    (tmp_path / "case_0_xx.vtu").write_text("a user's file, named like amfe 0.1's")
    (tmp_path / "case_old.vtp").write_text("a user's file, named like amfe 0.2's")
    (tmp_path / "mine.txt").write_text("not amfe's")
    vtu.write_fields_vtu(tmp_path, tiny_fields(k=1))
    # only what the earlier set listed (case_yy.vtu) goes: the set owns its files, no others
    assert sorted(os.listdir(tmp_path)) == ["case_0_xx.vtu", "case_old.vtp", "case_xx.vtu",
                                            "cases.json", "cases.pvd", "mine.txt"]
    before = {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)}
    bad = [(tiny_fields(nan=True), "non-finite"),
           (tiny_fields(names=["xx", "x/y"]), "case names"),
           (tiny_fields(names=["xx", "xx"]), "case names")]
    short = tiny_fields()
    short.radii = short.radii[:2]
    bad.append((short, "fields.radii has shape"))
    for fields, message in bad:
        with pytest.raises(AmfeError, match=message):
            vtu.write_fields_vtu(tmp_path, fields)
        assert {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)} == before
    with pytest.raises(AmfeError, match="JSON-serialisable"):
        vtu.write_fields_vtu(tmp_path, tiny_fields(), field_data={"x": object()})
        assert {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)} == before


def test_a_failed_write_leaves_no_collection(tmp_path, monkeypatch):
    vtu.write_fields_vtu(tmp_path, tiny_fields())
    calls = []

    def full_disk(path, mesh, **kw):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real(path, mesh, **kw)

    import meshio
    real = meshio.vtu.write
    monkeypatch.setattr(meshio.vtu, "write", full_disk)
    with pytest.raises(AmfeError, match="no cases.pvd was left|no space left"):
        vtu.write_fields_vtu(tmp_path, tiny_fields())
    assert "cases.pvd" not in os.listdir(tmp_path)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def vtk_reader():
    return pytest.importorskip("vtkmodules.vtkIOXML", reason="VTK's reader (ParaView's "
                               "python3-paraview or the vtk wheel) is not installed")


def test_vtk_reads_exactly_what_meshio_reads(tmp_path):
    """VTK's own reader and meshio's: the same points, ids and arrays, bit for bit."""
    xml = vtk_reader()
    import meshio
    from vtkmodules.util.numpy_support import vtk_to_numpy
    f = tiny_fields()
    f.displacement[1] += np.pi * 1e-7            # values with all 52 bits of mantissa
    for path in vtu.write_fields_vtu(tmp_path, f)[:-1]:
        reader = xml.vtkXMLUnstructuredGridReader()
        reader.SetFileName(path)
        reader.Update()
        assert reader.GetErrorCode() == 0
        out = reader.GetOutput()
        mesh = meshio.read(path)
        np.testing.assert_array_equal(vtk_to_numpy(out.GetPoints().GetData()), mesh.points)
        assert [out.GetCellType(k) for k in range(out.GetNumberOfCells())] == [3, 3]  # lines
        conn = vtk_to_numpy(out.GetCells().GetConnectivityArray()).reshape(-1, 2)
        np.testing.assert_array_equal(conn, mesh.cells_dict["line"])
        pd, cd = out.GetPointData(), out.GetCellData()
        assert {pd.GetArrayName(k) for k in range(pd.GetNumberOfArrays())} == set(mesh.point_data)
        assert {cd.GetArrayName(k) for k in range(cd.GetNumberOfArrays())} == set(mesh.cell_data)
        for name, arr in mesh.point_data.items():
            theirs = vtk_to_numpy(pd.GetArray(name))
            assert theirs.dtype == arr.dtype
            np.testing.assert_array_equal(theirs, arr)
        for name, (arr,) in mesh.cell_data.items():
            theirs = vtk_to_numpy(cd.GetArray(name))
            assert theirs.dtype == arr.dtype
            np.testing.assert_array_equal(theirs, arr)


def documented_arrays():
    """{array: unit} from the tables (| array | unit | meaning |) in docs/viewing.md's files."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "viewing.md").read_text()
    section = text.split("## The files", 1)[1].split("\n## ", 1)[0]
    out = {}
    for names, unit in re.findall(r"^\| (`[^|]+`) \| ([^|]+) \|", section, flags=re.M):
        for name in re.findall(r"`([a-z_A-Z]+)`", names):
            out[name] = unit.strip()
    return out


def test_every_documented_array_is_written_with_its_unit(tmp_path):
    documented = documented_arrays()
    assert len(documented) == len(vtu.POINT_ARRAYS) + len(vtu.CELL_ARRAYS)
    d = vtu.read_case(vtu.write_fields_vtu(tmp_path, tiny_fields())[0])
    assert set(documented) == set(d["point_data"]) | set(d["cell_data"])
    assert documented == d["field_data"]["units"]
    for name, unit in documented.items():     # the unit ends the name (SI)
        suffix = {"1": "", "m": "_m", "rad": "_rad", "N": "_N", "N m": "_Nm"}[unit]
        assert name.endswith(suffix)


def test_the_sidecar_and_collection_say_which_file_is_which(tmp_path):
    paths = vtu.write_fields_vtu(tmp_path, tiny_fields())
    side = json.loads((tmp_path / "cases.json").read_text())
    assert [c["file"] for c in side["cases"]] == ["case_xx.vtu", "case_yy.vtu"]
    assert side["amfe_version"] == "0.3.0" and side["bonds_not_drawn"] == 0
    assert pvd.case_fields(tmp_path / "elsewhere.vtu") == {}
    text = Path(paths[-1]).read_text()
    assert "DataArray" not in text and text.count("<DataSet ") == 2

"""ParaView output (amfe.io.vtp, amfe.io.vtkxml) and the bond end loads it holds."""
import os

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.io import vtp
from amfe.io.fields import Fields
from amfe.io.vtkxml import decode_binary, encode_binary, read_polydata
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


@pytest.mark.parametrize("dtype", ["float64", "int64", "uint8", "float32"])
@pytest.mark.parametrize("n", [0, 1, 7, 1000003])   # empty, one, a few, blocks of 1 MiB
@pytest.mark.parametrize("level", [None, 0, 1])
def test_binary_blocks_round_trip(dtype, n, level):
    a = (np.arange(n) * 3 - 5).astype(dtype)
    np.testing.assert_array_equal(decode_binary(encode_binary(a, level), dtype, n), a)
    with pytest.raises(AmfeError, match="values"):
        decode_binary(encode_binary(a, level), dtype, n + 1)


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
    paths = vtp.write_fields_vtp(tmp_path / "new" / "sub", f, field_data={"note": "hi"})
    assert [os.path.basename(p) for p in paths] == ["case_xx.vtp", "case_yy.vtp", "cases.pvd"]
    assert vtp.read_collection(paths[-1]) == [("xx", paths[0]), ("yy", paths[1])]
    for k in range(2):
        d = read_polydata(paths[k])
        np.testing.assert_array_equal(d["points"], f.centers)
        np.testing.assert_array_equal(d["lines"], f.bonds)
        assert set(d["point_data"]) == set(vtp.POINT_ARRAYS)
        assert set(d["cell_data"]) == set(vtp.CELL_ARRAYS)
        np.testing.assert_array_equal(d["cell_data"]["i"], [4, 4])
        np.testing.assert_array_equal(d["cell_data"]["j"], [7, 9])
        np.testing.assert_array_equal(d["cell_data"]["torsion_Nm"], f.torsion[k])
        np.testing.assert_array_equal(d["point_data"]["displacement_m"], f.displacement[k])
        fd = d["field_data"]
        assert fd["case_name"] == [("xx", "yy")[k]] and fd["note"] == ["hi"]
        assert fd["case_label"] == [f"{('xx', 'yy')[k]}: eps_xx = 1"]
        np.testing.assert_array_equal(fd["macro_strain_voigt"], [1, 0, 0, 0, 0, 0])
        # the largest displacement, times the warp factor, is 5 % of the box's largest side
        u = np.linalg.norm(f.displacement[k], axis=1).max()
        assert fd["warp_factor"][0] * u == pytest.approx(0.05 * 2e-5)
        assert "axial_force_N: N" in fd["units"]


def test_a_new_set_removes_the_old_one_and_bad_input_touches_nothing(tmp_path):
    (tmp_path / "case_0_xx.vtu").write_text("an older amfe's file")
    (tmp_path / "case_old.vtp").write_text("stale")
    (tmp_path / "mine.txt").write_text("not amfe's")
    vtp.write_fields_vtp(tmp_path, tiny_fields(k=1))
    assert sorted(os.listdir(tmp_path)) == ["case_xx.vtp", "cases.pvd", "mine.txt"]
    before = {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)}
    bad = [(tiny_fields(nan=True), "non-finite"),
           (tiny_fields(names=["xx", "x/y"]), "case names"),
           (tiny_fields(names=["xx", "xx"]), "case names")]
    short = tiny_fields()
    short.radii = short.radii[:2]
    bad.append((short, "fields.radii has shape"))
    for fields, message in bad:
        with pytest.raises(AmfeError, match=message):
            vtp.write_fields_vtp(tmp_path, fields)
        assert {p: (tmp_path / p).read_bytes() for p in os.listdir(tmp_path)} == before


def test_vtk_reads_what_the_numpy_reader_reads(tmp_path):
    xml = pytest.importorskip("vtkmodules.vtkIOXML", reason="VTK's reader (ParaView's "
                              "python3-paraview or the vtk wheel) is not installed")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    path = vtp.write_fields_vtp(tmp_path, tiny_fields())[1]
    reader = xml.vtkXMLPolyDataReader()
    reader.SetFileName(path)
    reader.Update()
    out = reader.GetOutput()
    ours = read_polydata(path)
    np.testing.assert_array_equal(vtk_to_numpy(out.GetPoints().GetData()), ours["points"])
    cd = out.GetCellData()
    for name, arr in ours["cell_data"].items():
        np.testing.assert_array_equal(vtk_to_numpy(cd.GetArray(name)), arr)
    assert out.GetPointData().GetVectors().GetName() == "displacement_m"
    assert out.GetFieldData().GetAbstractArray("case_label").GetValue(0) == "yy: eps_xx = 1"

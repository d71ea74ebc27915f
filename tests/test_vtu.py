"""ParaView output (amfe.io.vtu): round trip, the .pvd collection, validation, atomicity."""
import os
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from amfe.io import vtu
from amfe.errors import AmfeError


def _frame(seed=0, n=17, m=29):
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-1e-4, 1e-4, (n, 3))
    radii = rng.uniform(1.0e-5, 1.5e-5, n)
    pairs = set()
    while len(pairs) < m:
        i, j = rng.choice(n, 2, replace=False)
        pairs.add((int(min(i, j)), int(max(i, j))))
    bonds = np.array(sorted(pairs), dtype=np.int64)
    rng.shuffle(bonds)  # arbitrary bond order must survive
    cases = []
    for _ in range(6):
        cases.append({
            "displacement": rng.standard_normal((n, 3)) * 1e-7,
            "rotation": rng.standard_normal((n, 3)) * 1e-3,
            "axial_force": rng.standard_normal(m) * 1e-2,
            "shear_force": np.abs(rng.standard_normal(m)) * 1e-3,
            "moment": rng.standard_normal(m) * 1e-8,
        })
    return centers, radii, bonds, cases


def _block(mesh, cell_type):
    found = [k for k, c in enumerate(mesh.cells) if c.type == cell_type]
    assert len(found) == 1, [c.type for c in mesh.cells]
    return found[0]


def test_round_trip_six_cases(tmp_path):
    centers, radii, bonds, cases = _frame()
    n, m = len(radii), len(bonds)
    paths = vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    names = ["xx", "yy", "zz", "yz", "xz", "xy"]
    assert paths == [str(tmp_path / f"case_{k}_{nm}.vtu") for k, nm in enumerate(names)] \
        + [str(tmp_path / "cases.pvd")]
    for k, case in enumerate(cases):
        mesh = meshio.read(paths[k])
        assert mesh.points.dtype == np.float64
        np.testing.assert_array_equal(mesh.points, centers)
        kl, kv = _block(mesh, "line"), _block(mesh, "vertex")
        assert kl == 0  # cell id k is bond k
        np.testing.assert_array_equal(mesh.cells[kl].data, bonds)
        np.testing.assert_array_equal(mesh.cells[kv].data.ravel(), np.arange(n))
        for key in ("displacement", "rotation"):
            assert mesh.point_data[key].dtype == np.float64
            np.testing.assert_array_equal(mesh.point_data[key], case[key])
        np.testing.assert_array_equal(mesh.point_data["radius"], radii)
        for key in ("axial_force", "shear_force", "moment"):
            assert mesh.cell_data[key][kl].dtype == np.float64
            np.testing.assert_array_equal(mesh.cell_data[key][kl], case[key])
            np.testing.assert_array_equal(mesh.cell_data[key][kv], np.zeros(n))
        np.testing.assert_array_equal(mesh.cell_data["is_bond"][kl], np.ones(m))
        np.testing.assert_array_equal(mesh.cell_data["is_bond"][kv], np.zeros(n))
        # the helper reads the same thing
        back = vtu.read_case(paths[k])
        np.testing.assert_array_equal(back["bonds"], bonds)
        np.testing.assert_array_equal(back["moment"], case["moment"])
        np.testing.assert_array_equal(back["radius"], radii)
    # the cases really differ (no file written from the wrong case)
    a0 = meshio.read(paths[0]).cell_data["axial_force"][0]
    a1 = meshio.read(paths[1]).cell_data["axial_force"][0]
    assert not np.array_equal(a0, a1)


def test_binary_zlib(tmp_path):
    centers, radii, bonds, cases = _frame()
    paths = vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    root = ET.parse(paths[0]).getroot()
    assert root.get("type") == "UnstructuredGrid"
    assert root.get("compressor") == "vtkZLibDataCompressor"
    assert {da.get("format") for da in root.iter("DataArray")} == {"binary"}


def test_pvd_lists_all_cases(tmp_path):
    centers, radii, bonds, cases = _frame()
    paths = vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    pvd = tmp_path / "cases.pvd"
    assert paths[-1] == str(pvd)
    root = ET.parse(pvd).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    (coll,) = root.findall("Collection")
    datasets = coll.findall("DataSet")
    assert len(datasets) == 6
    steps = [float(ds.get("timestep")) for ds in datasets]
    assert steps == [0, 1, 2, 3, 4, 5]
    assert [ds.get("name") for ds in datasets] == ["xx", "yy", "zz", "yz", "xz", "xy"]
    for ds, path in zip(datasets, paths[:6]):
        f = ds.get("file")
        assert not os.path.isabs(f)
        assert (tmp_path / f).is_file()
        assert os.path.samefile(tmp_path / f, path)
    assert [p for _, _, p in vtu.read_collection(pvd)] == paths[:6]


def test_extra_arrays_and_custom_names(tmp_path):
    centers, radii, bonds, cases = _frame(n=9, m=12)
    cases = cases[:2]
    for k, c in enumerate(cases):
        c["point_data"] = {"layer": np.arange(9, dtype=np.int32), "s": np.full((9, 2), k + 0.5)}
        c["cell_data"] = {"a_star": np.linspace(0.1, 0.9, 12)}
    paths = vtu.write_load_cases(tmp_path / "new" / "sub", centers, radii, bonds, cases,
                                 names=["a", "b-2"])
    assert [os.path.basename(p) for p in paths] == ["case_0_a.vtu", "case_1_b-2.vtu", "cases.pvd"]
    mesh = meshio.read(paths[1])
    np.testing.assert_array_equal(mesh.point_data["layer"], np.arange(9))
    np.testing.assert_array_equal(mesh.point_data["s"], np.full((9, 2), 1.5))
    kl, kv = _block(mesh, "line"), _block(mesh, "vertex")
    np.testing.assert_array_equal(mesh.cell_data["a_star"][kl], np.linspace(0.1, 0.9, 12))
    np.testing.assert_array_equal(mesh.cell_data["a_star"][kv], np.zeros(9))


def test_no_bonds_still_shows_particles(tmp_path):
    centers, radii, _, cases = _frame(n=5, m=1)
    cases = [{"displacement": c["displacement"][:5], "rotation": c["rotation"][:5],
              "axial_force": [], "shear_force": [], "moment": []} for c in cases]
    paths = vtu.write_load_cases(tmp_path, centers, radii, np.zeros((0, 2), int), cases)
    mesh = meshio.read(paths[0])
    assert [c.type for c in mesh.cells] == ["vertex"]
    back = vtu.read_case(paths[0])
    assert back["bonds"].shape == (0, 2) and back["axial_force"].shape == (0,)


def test_old_set_replaced(tmp_path):
    centers, radii, bonds, cases = _frame(seed=1)
    vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    (tmp_path / "notes.txt").write_text("mine")
    centers2, radii2, bonds2, cases2 = _frame(seed=2, n=11, m=15)
    vtu.write_load_cases(tmp_path, centers2, radii2, bonds2, cases2[:2], names=["p", "q"])
    assert sorted(os.listdir(tmp_path)) == ["case_0_p.vtu", "case_1_q.vtu", "cases.pvd",
                                            "notes.txt"]
    mesh = meshio.read(tmp_path / "case_1_q.vtu")
    np.testing.assert_array_equal(mesh.points, centers2)
    np.testing.assert_array_equal(mesh.point_data["rotation"], cases2[1]["rotation"])


def _bad_inputs():
    centers, radii, bonds, cases = _frame()

    def with_case(k, key, value):
        cs = [dict(c) for c in cases]
        cs[k][key] = value
        return centers, radii, bonds, cs

    nan_disp = cases[2]["displacement"].copy()
    nan_disp[3, 1] = np.nan
    inf_force = cases[5]["axial_force"].copy()
    inf_force[0] = np.inf
    return {
        "centers (N,2)": (centers[:, :2], radii, bonds, cases),
        "radii too short": (centers, radii[:-1], bonds, cases),
        "nan centre": (np.where(np.arange(len(radii))[:, None] == 4, np.nan, centers),
                       radii, bonds, cases),
        "bonds (M,3)": (centers, radii, np.c_[bonds, bonds[:, :1]], cases),
        "bond index out of range": (centers, radii, np.vstack([bonds, [0, len(radii)]]), cases),
        "self bond": (centers, radii, np.vstack([bonds, [3, 3]]), cases),
        "float bonds": (centers, radii, bonds + 0.5, cases),
        "displacement (N,2)": with_case(1, "displacement", cases[1]["displacement"][:, :2]),
        "rotation (N-1,3)": with_case(0, "rotation", cases[0]["rotation"][1:]),
        "axial_force (M-1,)": with_case(3, "axial_force", cases[3]["axial_force"][1:]),
        "moment (M,1)": with_case(4, "moment", cases[4]["moment"][:, None]),
        "nan displacement": with_case(2, "displacement", nan_disp),
        "inf axial force": with_case(5, "axial_force", inf_force),
        "missing shear": (centers, radii, bonds,
                          [{k: v for k, v in c.items() if k != "shear_force"} for c in cases]),
        "unknown key": with_case(0, "stress", np.zeros(3)),
        "bad extra shape": with_case(0, "cell_data", {"x": np.zeros(len(radii))}),
        "reserved extra name": with_case(0, "point_data", {"radius": radii}),
        "five cases, default names": (centers, radii, bonds, cases[:5]),
    }


@pytest.mark.parametrize("label", list(_bad_inputs()))
def test_bad_input_raises_and_writes_nothing(tmp_path, label):
    centers, radii, bonds, cases = _bad_inputs()[label]
    with pytest.raises(AmfeError):
        vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    assert os.listdir(tmp_path) == []
    missing = tmp_path / "not_created"
    with pytest.raises(AmfeError):
        vtu.write_load_cases(missing, centers, radii, bonds, cases)
    assert not missing.exists()


@pytest.mark.parametrize("names", [["xx"] * 6, ["a/b", "yy", "zz", "yz", "xz", "xy"], ["xx"],
                                   "xxyyzz"])
def test_bad_names(tmp_path, names):
    centers, radii, bonds, cases = _frame()
    with pytest.raises(AmfeError):
        vtu.write_load_cases(tmp_path, centers, radii, bonds, cases, names=names)
    assert os.listdir(tmp_path) == []


def _crash_on_third(monkeypatch):
    real = meshio.write
    calls = []

    def flaky(path, mesh, *args, **kwargs):
        calls.append(path)
        if len(calls) == 3:
            with open(path, "w") as f:  # a half-written file, as after a full disk
                f.write("<VTKFile")
            raise OSError(28, "No space left on device")
        return real(path, mesh, *args, **kwargs)

    monkeypatch.setattr(meshio, "write", flaky)
    return calls


def test_crash_leaves_no_pvd_and_no_temporaries(tmp_path, monkeypatch):
    centers, radii, bonds, cases = _frame()
    calls = _crash_on_third(monkeypatch)
    with pytest.raises(AmfeError, match="No space left"):
        vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    assert len(calls) == 3
    left = os.listdir(tmp_path)
    assert "cases.pvd" not in left
    assert not [f for f in left if f.startswith(".") or f.endswith(".tmp")], left


def test_crash_over_old_set_removes_old_pvd(tmp_path, monkeypatch):
    centers, radii, bonds, cases = _frame(seed=3)
    vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    assert (tmp_path / "cases.pvd").exists()
    _crash_on_third(monkeypatch)
    with pytest.raises(AmfeError):
        vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    left = os.listdir(tmp_path)
    assert "cases.pvd" not in left  # a stale collection must not look current
    assert not [f for f in left if f.startswith(".") or f.endswith(".tmp")], left
    # a later successful write restores a complete set
    monkeypatch.undo()
    vtu.write_load_cases(tmp_path, centers, radii, bonds, cases)
    assert len(vtu.read_collection(tmp_path / "cases.pvd")) == 6

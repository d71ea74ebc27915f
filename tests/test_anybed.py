"""The surrogate for any bed (issue 46): the size rule, the anybed network and its input,
the routes, and `amfe predict` / `amfe.predict` on beds no shipped model reads as they are.

Checks against what must hold exactly: the size rule's weights (linear in 1/L, one model
at a shipped size), the anybed network started from a 3-layer model gives that model's
output bit for bit (to float32 rounding) on its beds, E enters by exact scaling, the
imaging is the data sets' own, Python and the command line give the same numbers, and
a batch keeps going past a bed outside every range.
"""
import json

import h5py
import numpy as np
import pytest
import torch
from helpers import run_cli

import amfe
from amfe.errors import AmfeError
from amfe.model.material import Material
from amfe.model.scales import bed_for, record_seed
from amfe.training.anybed import MAX_LAYERS, anybed_input, from_small
from amfe.training.anypredict import bed_images, route_of
from amfe.training.multiscale import MultiScaleNet
from amfe.training.sizerule import size_weights

THIN = "box600x600x200um_nu250to400psi40to120"


def test_the_size_rule_is_linear_in_one_over_l_and_exact_at_the_shipped_sizes():
    for s in (0.6, 1.2, 3.0):
        assert size_weights(s, s) == [(s, 1.0)]
    (a, wa), (b, wb) = size_weights(0.9, 0.9)
    assert (a, b) == (0.6, 1.2) and wb == pytest.approx((1 / 0.9 - 1 / 0.6) / (1 / 1.2 - 1 / 0.6))
    (a, wa), (b, wb) = size_weights(2.0, 2.0)
    assert (a, b) == (1.2, 3.0) and wa + wb == pytest.approx(1.0) and 0 < wa < 1
    (a, wa), (b, wb) = size_weights(4.0, 4.0)        # past 3 mm: extrapolated from 1.2 and 3
    assert (a, b) == (1.2, 3.0) and wa < 0 < wb and wa + wb == pytest.approx(1.0)
    # a rectangle reads 1/L as the mean of 1/Lx and 1/Ly
    rect, square = size_weights(0.6, 2.4), size_weights(0.96, 0.96)
    assert [s for s, _ in rect] == [s for s, _ in square]
    np.testing.assert_allclose([w for _, w in rect], [w for _, w in square], rtol=1e-12)
    for bad in ((0.5, 0.5), (4.5, 4.5), (0.6, 5.0)):
        with pytest.raises(AmfeError, match=f"{bad[0]:g} x {bad[1]:g} mm"):
            size_weights(*bad)


def test_anybed_starts_as_the_three_layer_model_and_pads_absent_layers():
    torch.manual_seed(0)
    small = MultiScaleNet((6, 20, 20), width=0.125, n_fill=3).eval()
    net = from_small(small.state_dict(), (20, 20), width=0.125).eval()
    rng = np.random.default_rng(0)
    fill, bonds = rng.random((4, 3, 20, 20)), rng.random((4, 3, 20, 20))
    x = np.stack([anybed_input(f, b, 0.28, 0.08) for f, b in zip(fill, bonds)])
    with torch.no_grad():
        ref = small(torch.as_tensor(np.concatenate([fill, bonds], 1), dtype=torch.float32))
        got = net(torch.as_tensor(x))
    np.testing.assert_allclose(got.numpy(), ref.numpy(), rtol=0, atol=1e-5)
    one = anybed_input(fill[0][:2], bonds[0][:2], 0.3, 0.1)
    assert one.shape == (2 * MAX_LAYERS + 3, 20, 20)
    assert np.all(one[2:MAX_LAYERS] == 1.0) and np.all(one[MAX_LAYERS + 2:2 * MAX_LAYERS] == 0)
    np.testing.assert_allclose(one[2 * MAX_LAYERS:, 0, 0], [-1 / 3, 0.2, 0.5], atol=1e-6)
    for layers, nu, psi, what in ((7, 0.3, 0.08, "7 powder layers"), (3, 0.45, 0.08, "nu is 0.45"),
                                  (3, 0.3, 0.2, "psi is 0.2")):
        with pytest.raises(AmfeError, match=what):
            route_of(layers, 0.6, 0.6, nu, psi)


def test_routes_by_kind_of_bed():
    assert route_of(3, 0.9, 0.9, 0.28, 0.08) == "size rule"
    assert route_of(2, 0.6, 0.6, 0.28, 0.08) == "anybed"
    assert route_of(3, 0.6, 0.6, 0.33, 0.08) == "anybed"
    assert route_of(4, 2.0, 2.0, 0.28, 0.08) == "anybed x size rule"


def test_the_images_are_the_data_sets_own(tmp_path):
    data = tmp_path / "d.h5"
    proc = run_cli(["dataset", "-o", str(data), "--count", "1", "--seed", "5",
                    "--size", "0.6", "0.6", "0.2", "--materials", "draw", "--no-progress"])
    assert proc.returncode == 0, proc.stderr
    bed = bed_for(THIN, record_seed(5, 0))
    fill, bonds, box = bed_images(bed, bed.attrs["size"])
    with h5py.File(data) as f:
        np.testing.assert_array_equal(fill, f["images"][0])
        np.testing.assert_array_equal(bonds, f["bond_images"][0])
    assert box == pytest.approx((0.6e-3, 0.6e-3, 0.2e-3))


@pytest.fixture(scope="module")
def thin_bed(tmp_path_factory):
    path = tmp_path_factory.mktemp("anybed") / "thin.h5"
    bed = bed_for(THIN, record_seed(7, 0))
    amfe.write_bed(str(path), bed)
    return path, bed


def test_predict_reads_a_thin_bed_of_its_own_material_and_scales_e_exactly(thin_bed, tmp_path):
    path, bed = thin_bed
    p = amfe.predict(str(path))
    assert p.source == "surrogate" and p.to_dict()["route"] == "anybed"
    assert p.intervals is not None and set(p.intervals) >= {"Ex", "nu_xy"}
    stiff = amfe.Bed(bed.centers, bed.radii,
                     attrs={**bed.attrs, "material_E": 2 * float(bed.attrs["material_E"])})
    q = amfe.predict(stiff)
    for k in ("Ex", "Ey", "Ez"):
        assert q.properties[k] == pytest.approx(2 * p.properties[k], rel=1e-12)
    for k in ("nu_yz", "nu_xz", "nu_xy"):
        assert q.properties[k] == pytest.approx(p.properties[k], rel=1e-12)
    out = tmp_path / "p.json"
    proc = run_cli(["predict", str(path), "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    cli = json.loads(out.read_text())["beds"][0]
    assert cli["properties"] == p.to_dict()["properties"]
    assert cli["intervals"] == p.to_dict()["intervals"]


def test_a_batch_predicts_around_a_bed_outside_every_range(thin_bed, tmp_path):
    path, _ = thin_bed
    tiny = tmp_path / "tiny.h5"
    amfe.write_bed(str(tiny), amfe.generate_bed(size=(0.5e-3, 0.5e-3, 0.3e-3), seed=1))
    out = tmp_path / "p.json"
    proc = run_cli(["predict", str(tiny), str(path), "-o", str(out)])
    assert proc.returncode == 3, proc.stderr
    beds = json.loads(out.read_text())["beds"]
    assert beds[0]["source"] == "failed" and "0.5 x 0.5 mm" in beds[0]["error"]
    assert beds[1]["source"] == "surrogate"


def test_a_bed_without_a_recorded_size_is_imaged_on_its_spheres_box(thin_bed):
    _, bed = thin_bed
    bare = amfe.Bed(bed.centers, bed.radii,
                    attrs={k: v for k, v in bed.attrs.items() if k != "size"})
    p = amfe.predict(bare)
    assert any("records no size" in n for n in p.to_dict()["notes"])


def test_material_out_of_the_trained_range_is_refused_with_its_value(thin_bed):
    _, bed = thin_bed
    soft = amfe.Bed(bed.centers, bed.radii, attrs={**bed.attrs, "material_nu": 0.45})
    p = amfe.predict(soft)
    assert p.source == "failed" and "0.45" in p.error


def test_material_helper_is_the_beds():
    m = Material(E=114e9, nu=0.34, psi=0.08)
    assert route_of(3, 0.6, 0.6, m.nu, m.psi) == "anybed"


def test_a_material_given_for_the_bed_is_the_one_written_in_its_file(tmp_path):
    """amfe predict --E --nu --psi (and amfe.predict(material=...)) give what a bed file with
    that material gives, route included, and --check solves the bed with it: the solve
    equals amfe.homogenize with the same material; the record says where it came from."""
    bed = amfe.generate_bed(size=(0.6e-3, 0.6e-3, 0.3e-3), seed=3)      # steel, small
    given = {"E": 114e9, "nu": 0.33, "psi": 0.06}
    written = amfe.Bed(bed.centers, bed.radii, attrs={
        **bed.attrs, **{f"material_{k}": v for k, v in given.items()}})
    want = amfe.predict(written).to_dict()
    assert want["route"] == "anybed" and want["source"] == "surrogate"
    got = amfe.predict(bed, material=given).to_dict()
    assert got["properties"] == want["properties"] and got["intervals"] == want["intervals"]
    assert any("material from the argument" in n for n in got["notes"])
    path, out = tmp_path / "steel.h5", tmp_path / "p.json"
    amfe.write_bed(str(path), bed)
    proc = run_cli(["predict", str(path), "--E", "114e9", "--nu", "0.33", "--psi", "0.06",
                    "--check", "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    rec = json.loads(out.read_text())["beds"][0]
    assert rec["properties"] == want["properties"]
    assert rec["material"] == {**given, "source": "command line"}
    solved = amfe.homogenize(bed, material=Material(**given)).properties
    for k in ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy"):
        assert rec["check"]["solver"][k] == pytest.approx(solved[k], rel=1e-6)


def test_a_size_between_the_shipped_ones_is_the_rule_over_the_torch_networks(tmp_path):
    """A 0.66 x 0.66 mm bed: the shipped models read its 22 x 22 image (fully convolutional),
    and its prediction is the size rule's mix of their members, here recomputed with torch
    (the numpy inference, amfe.training.npnet, must not refuse the other image size)."""
    from amfe.training.ensemble import predict_raw
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import SHIPPED, models_dir
    bed = amfe.generate_bed(size=(0.66e-3, 0.66e-3, 0.3e-3), seed=2)
    p = amfe.predict(bed)
    assert p.source == "surrogate" and p.to_dict()["route"] == "size rule"
    fill, bonds, box = bed_images(bed, bed.attrs["size"])
    x = torch.from_numpy(np.concatenate([fill, bonds])[None])
    members = 0.0
    for size, w in size_weights(box[0] * 1e3, box[1] * 1e3):
        name = SHIPPED[{0.6: "small", 1.2: "medium"}[size]]
        sur = Surrogate.load(models_dir() / name, backend="torch")
        members = members + w * np.stack([predict_raw(net, x, sur.norm, sur.tta).numpy()
                                          for net in sur.nets])
    want = members.mean(axis=0)[0]
    got = np.array([p.properties[k] for k in ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy")])
    np.testing.assert_allclose(got, want, rtol=1e-5)

"""A stiffness-head model through the predict path: trained with ``amfe train --head stiffness``
on a tiny data set, loaded by Surrogate.load / amfe predict like a six-constant model.

What must hold (issue 34, item 3): the predicted C is symmetric positive definite; the six
constants are those of C; the prediction of a mirrored bed is the mirrored prediction (C moved
as a tensor); a batch equals one-at-a-time; the six-constant path is unchanged.
"""
import itertools
import json

import h5py
import numpy as np
import pytest
import torch
from cli_fixtures import TINY_ATTRS, _tiny_bed, run_main
from test_training import write_synthetic

from amfe.training.data import flip_images
from amfe.training.stiffness import constants_from_stiffness, transform_stiffness

ARCH = {"width": 0.125, "hidden": [16]}


def add_stiffness(path, seed=0):
    """Give the synthetic data set a /C (n, 6, 6) [Pa]: SPD, anisotropic, tied to the images."""
    rng = np.random.default_rng(seed)
    with h5py.File(path, "a") as f:
        d = np.asarray(f["density"])
        n = d.size
        C = np.empty((n, 6, 6))
        for k in range(n):
            A = 0.15 * rng.standard_normal((6, 6))
            iso = np.diag([2.0, 2.0, 2.4, 0.6, 0.6, 0.6])
            iso[:3, :3] += 0.6 * (1 - np.eye(3))
            C[k] = 1e11 * np.exp(2 * d[k]) * (iso + A @ A.T)
        f["C"] = C
    return path


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """(six-constant multiscale model, stiffness model, data set, directory)."""
    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.train import TrainConfig, train_model
    d = tmp_path_factory.mktemp("stiffpred")
    data = str(add_stiffness(write_synthetic(d / "tiny.h5", n=40, shape=(1, 5, 5),
                                             attrs=TINY_ATTRS)))
    cfg = TrainConfig(arch="multiscale", arch_args=ARCH, epochs=1, batch_size=8, members=2,
                      seed=1)
    six = save_checkpoint(d / "six.pt", train_model(data, cfg, progress=False,
                                                    log=lambda line: None))
    torch.set_num_threads(1)
    code, out, err = run_main(["train", data, "--head", "stiffness", "--init", six,
                               "--members", "2", "--epochs", "2", "--batch-size", "8",
                               "--loss", "constants", "--augment", "d4", "--tta", "d4",
                               "--seed", "1", "--quiet", "-o", d / "stiff.pt"])
    assert code == 0, err
    return six, str(d / "stiff.pt"), data, d


def images_of(data, n=6):
    with h5py.File(data, "r") as f:
        return np.asarray(f["images"][:n], np.float32)


def test_predicted_stiffness_is_spd_and_symmetric(models):
    from amfe.training.predict import Surrogate
    sur = Surrogate.load(models[1])
    res = sur.predict(images_of(models[2]))
    C = res["stiffness"]
    assert C.shape == (6, 6, 6)
    np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
    assert np.linalg.eigvalsh(C).min() > 0
    # Not a trivial output: the beds' C differ.
    assert np.ptp(C[:, 0, 0]) > 1e-6 * C[0, 0, 0]


def test_six_constants_are_those_of_the_predicted_stiffness(models):
    from amfe.training.predict import Surrogate
    res = Surrogate.load(models[1]).predict(images_of(models[2]))
    nine = constants_from_stiffness(res["stiffness"])
    np.testing.assert_allclose(res["mean"], nine[:, :6], rtol=1e-10)
    np.testing.assert_allclose(res["constants9"], nine, rtol=1e-10)


@pytest.mark.parametrize("sym", [s for s in itertools.product([False, True], repeat=3) if any(s)])
def test_prediction_is_equivariant(models, sym):
    """The d4-averaged C of a mirrored / transposed bed is the bed's C moved as a tensor."""
    from amfe.training.predict import Surrogate
    sur = Surrogate.load(models[1])
    x = images_of(models[2])
    C = sur.predict(x)["stiffness"]
    Cs = sur.predict(flip_images(torch.from_numpy(x), *sym).numpy())["stiffness"]
    np.testing.assert_allclose(Cs, transform_stiffness(C, *sym), rtol=1e-5, atol=1e-6 * C.max())
    if sym[0] or sym[1]:   # a mirror changes the sign of couplings the net does predict
        assert np.abs(C[:, 0, 4]).max() > 1e-6 * C.max()


def test_batch_equals_one_at_a_time(models):
    from amfe.training.predict import Surrogate
    sur = Surrogate.load(models[1])
    x = images_of(models[2], 8)
    batch = sur.predict(x)
    for k in range(len(x)):
        one = sur.predict(x[k:k + 1])
        for key in ("mean", "stiffness", "constants9", "spread"):
            np.testing.assert_allclose(batch[key][k], one[key][0], rtol=1e-6, atol=0, err_msg=key)


def test_members_mean_stiffness(models):
    """C is the mean of the members' C; the spread is that of the members' six constants."""
    from amfe.training.predict import Surrogate
    from amfe.training.stiffness import predict_stiffness
    sur = Surrogate.load(models[1])
    x = torch.from_numpy(images_of(models[2]))
    scale = sur.ckpt["stiffness_scale"]
    each = [predict_stiffness(net, x, tta="d4", scale=scale) for net in sur.nets]
    res = sur.predict(x.numpy())
    np.testing.assert_allclose(res["stiffness"], np.mean(each, axis=0), rtol=1e-6)
    six = np.stack([constants_from_stiffness(c)[:, :6] for c in each])
    np.testing.assert_allclose(sur.member_outputs(x.numpy()), six, rtol=1e-6)


def test_six_constant_path_is_unchanged(models):
    """A six-constant model: the members' TTA-averaged decoded outputs, no stiffness keys."""
    from amfe.training.ensemble import predict_raw
    from amfe.training.predict import Surrogate
    sur = Surrogate.load(models[0], backend="torch")
    x = images_of(models[2])
    res = sur.predict(x)
    assert "stiffness" not in res and "constants9" not in res
    want = np.mean([predict_raw(net, torch.from_numpy(x), sur.norm, sur.tta).numpy()
                    for net in sur.nets], axis=0)
    np.testing.assert_allclose(res["mean"], want, rtol=1e-12)
    # the default, numpy inference (amfe.training.npnet): the same to float32 rounding
    np.testing.assert_allclose(Surrogate.load(models[0]).predict(x)["mean"], want, rtol=1e-5)


def test_amfe_predict_writes_stiffness_and_shear(models):
    six, stiff, data, d = models
    bed = _tiny_bed(str(d / "bed.h5"))
    code, out, err = run_main(["predict", bed, "--model", stiff, "-o", d / "p.json"])
    assert code == 0, err
    got = json.loads((d / "p.json").read_text())["beds"][0]
    C = np.array(got["stiffness"]["C"])
    nine = constants_from_stiffness(C)[0]
    names = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy")
    for k, name in enumerate(names):
        assert got["stiffness"]["constants"][name] == pytest.approx(nine[k], rel=1e-9)
        assert got["properties"][name] == pytest.approx(nine[k], rel=1e-9)
    for name in names[6:]:
        line = next(ln for ln in out.splitlines() if ln.strip().startswith(name))
        assert float(line.split()[1]) == pytest.approx(nine[names.index(name)] / 1e9, rel=1e-5)
    # The six-constant model's JSON has no stiffness block.
    code, out, err = run_main(["predict", bed, "--model", six, "-o", d / "q.json"])
    assert code == 0, err
    assert "stiffness" not in json.loads((d / "q.json").read_text())["beds"][0]
    assert "G_yz" not in out


def test_intervals_for_all_nine(models):
    """run/train/calibrate_intervals.py calibrates a stiffness model's nine constants (the shear
    moduli's labels from /C); amfe predict then gives each of the nine its interval."""
    from run.train import calibrate_intervals as mod
    six, stiff, data, d = models
    assert mod.main([stiff, data, "-o", str(d / "cal.pt"), "--coverage", "0.8"]) == 0
    ckpt = torch.load(d / "cal.pt", weights_only=True)
    cal = next(iter(ckpt["conformal"]["sizes"].values()))
    assert list(cal["quantile"]) == ["Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy",
                                     "G_yz", "G_xz", "G_xy"]
    # The calibration beds' coverage is the conformal rank's: at least 80 % of them per constant.
    from amfe.training.conformal import intervals
    from amfe.training.data import dataset_info
    from amfe.training.predict import Surrogate
    sur = Surrogate(ckpt, "cal")
    names, pred, labels, spread9 = mod.predictions(sur, data, dataset_info(data, sur.inputs))
    lo, hi = intervals(pred, names, cal, spread9)
    inside = ((labels >= lo) & (labels <= hi)).mean(axis=0)
    assert (inside >= 0.8).all() and (inside < 1).any()
    bed = _tiny_bed(str(d / "bed.h5"))
    code, out, err = run_main(["predict", bed, "--model", d / "cal.pt", "-o", d / "c.json"])
    assert code == 0, err
    got = json.loads((d / "c.json").read_text())["beds"][0]
    assert set(got["intervals"]) == set(names)
    for name in names:
        lo_, hi_ = got["intervals"][name]
        assert lo_ <= got["stiffness"]["constants"][name] <= hi_
    assert "[" in next(ln for ln in out.splitlines() if ln.strip().startswith("G_xy"))


def test_raw_of_stiffness_inverts_the_head():
    from amfe.training.stiffness import stiffness_from_raw
    from amfe.training.stiffness_train import raw_of_stiffness
    rng = np.random.default_rng(3)
    A = rng.standard_normal((20, 6, 6))
    C = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(6)
    np.testing.assert_allclose(stiffness_from_raw(raw_of_stiffness(C)).numpy(), C, rtol=1e-9,
                               atol=1e-12)


def test_constants_loss_is_the_mean_relative_error_of_the_nine():
    from amfe.training.stiffness import stiffness_from_raw
    from amfe.training.stiffness_train import constants_loss
    torch.manual_seed(0)
    raw = torch.randn(7, 21, dtype=torch.float64)
    C_true = stiffness_from_raw(torch.randn(7, 21, dtype=torch.float64))
    pred = constants_from_stiffness(stiffness_from_raw(raw).numpy())
    true = constants_from_stiffness(C_true.numpy())
    rel = np.abs(pred - true) / np.abs(true)
    assert float(constants_loss(raw, C_true)) == pytest.approx(rel.mean(), rel=1e-10)
    w = np.array([1, 1, 1, 2, 2, 2, 1, 1, 1]) / 12
    assert float(constants_loss(raw, C_true, nu_weight=2)) == pytest.approx(
        (rel * w).sum(axis=1).mean(), rel=1e-10)


def test_augmentation_moves_the_stiffness_with_the_image():
    from amfe.training.stiffness_train import augment_tensor
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(64, 2, 5, 5)
    A = torch.randn(64, 6, 6, dtype=torch.float64)
    C = A @ A.transpose(1, 2)
    xa, Ca = augment_tensor(x, C, "d4", gen)
    seen = set()
    for k in range(64):
        sym = next(s for s in itertools.product([False, True], repeat=3)
                   if torch.equal(flip_images(x[k:k + 1], *s), xa[k:k + 1]))
        seen.add(sym)
        np.testing.assert_allclose(Ca[k].numpy(), transform_stiffness(C[k].numpy(), *sym),
                                   rtol=1e-12)
    assert len(seen) == 8   # every symmetry drawn, so the check covers them all


def test_stiffness_head_options_are_checked(models, tmp_path):
    from cli_fixtures import assert_one_error
    six, stiff, data, d = models
    code, _, err = run_main(["train", data, "--head", "stiffness", "-o", tmp_path / "a.pt"])
    assert "--init" in assert_one_error(code, err, "train")
    code, _, err = run_main(["train", data, "--loss", "constants", "-o", tmp_path / "b.pt"])
    assert "constants" in assert_one_error(code, err, "train")
    code, _, err = run_main(["train", data, "--head", "stiffness", "--init", six, "--arch",
                             "vgg", "-o", tmp_path / "c.pt"])
    assert "--arch" in assert_one_error(code, err, "train")


def test_a_stiffness_model_is_fine_tuned_on_another_bed_size_with_its_own_head(models, tmp_path):
    """--init a stiffness model, data of another in-plane size (7 x 7 against 5 x 5): accepted;
    the last layer and stiffness_scale are the initial model's (no ridge re-fit: with lr 1e-9
    Adam moves a weight by at most ~1e-9 a step), the image shape the new data's."""
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.stiffness import N_CHOLESKY
    six, stiff, data, d = models
    other = str(add_stiffness(write_synthetic(tmp_path / "seven.h5", n=30, shape=(1, 7, 7),
                                              attrs=TINY_ATTRS, seed=3), seed=5))
    code, out, err = run_main(["train", other, "--head", "stiffness", "--init", stiff,
                               "--init-member", "1", "--epochs", "1", "--batch-size", "8",
                               "--lr", "1e-9", "--loss", "constants", "--seed", "4", "--quiet",
                               "-o", tmp_path / "tuned.pt"])
    assert code == 0, err
    start, tuned = load_checkpoint(stiff), load_checkpoint(tmp_path / "tuned.pt")
    assert list(tuned["image_shape"]) == [1, 7, 7] and list(start["image_shape"]) == [1, 5, 5]
    assert tuned["stiffness_scale"] == start["stiffness_scale"]
    last = [k for k, v in start["members"][1].items() if v.shape[:1] == (N_CHOLESKY,)]
    assert len(last) == 2   # the last layer's weight and bias
    for k in last:
        torch.testing.assert_close(tuned["members"][0][k], start["members"][1][k],
                                   rtol=0, atol=1e-7)
    # a six-constant --init of the same data gets a fitted head: not the stiffness model's
    code, out, err = run_main(["train", other, "--head", "stiffness", "--init", six,
                               "--init-member", "1", "--epochs", "1", "--batch-size", "8",
                               "--lr", "1e-9", "--loss", "constants", "--seed", "4", "--quiet",
                               "-o", tmp_path / "fitted.pt"])
    assert code == 0, err
    fitted = load_checkpoint(tmp_path / "fitted.pt")
    assert not torch.allclose(fitted["members"][0][last[0]], start["members"][1][last[0]])

"""The flag's error network (issue 46): its Laplace tail probabilities against closed forms
and sampling, its numpy inference against torch, mirror invariance, the file round trip,
and a flag file that names it (the risk reads its logit as one more feature)."""
import json

import numpy as np
import pytest
import torch

from amfe.errors import AmfeError
from amfe.training.flagnet import SCALE, bad_logit, load_flagnet, save_flagnet, tail_probabilities
from amfe.training.flagrisk import (
    bed_risk,
    features,
    fit,
    load_flag,
    model_features,
    risk,
    with_flagnet,
)
from amfe.training.multiscale import MultiScaleNet
from amfe.vocab import LABEL_NAMES
from run.train import train_flagnet

ARGS = {"n_fill": 3, "channels": [4, 8], "hidden": [8]}
SHAPE = (6, 8, 8)


def test_tail_probability_is_the_laplace_tail():
    b = np.array([[0.3, 1.0, 2.0, 5.0, 0.1, 1.5]])
    t = 0.1 / SCALE
    # centred: P(|r| > t) = exp(-t / b)
    assert np.allclose(tail_probabilities(np.zeros((1, 6)), np.log(b), 0.1), np.exp(-t / b))
    # off centre, against sampling
    rng = np.random.default_rng(0)
    mu, logb = np.array([[1.0, -3.0, 2.5, 0.0, -1.0, 4.0]]), np.log(b)
    r = rng.laplace(mu, np.exp(logb), size=(400_000, 6))
    assert np.allclose(tail_probabilities(mu, logb, 0.1)[0], (np.abs(r) > t).mean(0), atol=3e-3)


def test_bad_logit_is_finite_and_matches_its_torch_twin():
    rng = np.random.default_rng(1)
    mu = rng.normal(scale=[[1], [50]], size=(2, 6)).repeat(50, 0) * rng.random((100, 1))
    logb = rng.uniform(-8, 8, size=(100, 6))
    got = bad_logit(mu, logb, 0.1)
    assert np.all(np.isfinite(got))
    twin = train_flagnet.bad_logit(torch.as_tensor(mu), torch.as_tensor(logb), 0.1).numpy()
    assert np.allclose(got, twin, rtol=1e-9, atol=1e-9)
    # independent constants: 1 - P(bad) is the product of each one's P(inside)
    mu1, logb1 = np.zeros((1, 6)), np.zeros((1, 6))
    p = 1 / (1 + np.exp(-bad_logit(mu1, logb1, 0.1)))
    assert p[0] == pytest.approx(1 - (1 - np.exp(-0.1 / SCALE)) ** 6, rel=1e-9)


def _net(seed=0):
    torch.manual_seed(seed)
    return MultiScaleNet(SHAPE, outputs=12, **ARGS)


def _saved(tmp_path, nets):
    path = tmp_path / "flag_net.npz"
    states = [{k: v.detach().numpy() for k, v in n.state_dict().items()} for n in nets]
    save_flagnet(path, states, {"image_shape": list(SHAPE), "arch_args": ARGS})
    return path


def test_numpy_inference_matches_torch_and_is_mirror_invariant(tmp_path):
    nets = [_net(0), _net(1)]
    for n in nets:   # the weights as the file keeps them
        n.load_state_dict({k: v.half().float() for k, v in n.state_dict().items()})
        n.eval()
    flagnet = load_flagnet(_saved(tmp_path, nets))
    x = np.random.default_rng(2).random((5,) + SHAPE).astype(np.float32)
    mu, logb = flagnet.outputs(x)
    with torch.no_grad():
        t = torch.as_tensor(x)
        views = [t, t.flip(-1).flip(-2), t.flip(-1), t.flip(-2)]
        ref = np.mean([n(v).numpy() for n in nets for v in views], axis=0)
    assert np.allclose(mu, ref[:, :6], atol=1e-5)
    assert np.allclose(logb, np.clip(ref[:, 6:], -5, 5), atol=1e-5)
    for flip in (lambda a: a[..., ::-1], lambda a: a[..., ::-1, :]):
        m2, l2 = flagnet.outputs(np.ascontiguousarray(flip(x)))
        assert np.allclose(m2, mu, atol=1e-5) and np.allclose(l2, logb, atol=1e-5)
    with pytest.raises(AmfeError, match="shape"):
        flagnet.outputs(x[:, :4])


def test_a_foreign_file_is_refused(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, header=np.frombuffer(json.dumps({"format": "x"}).encode(), np.uint8))
    with pytest.raises(AmfeError, match="not an amfe flag error network"):
        load_flagnet(path)
    with pytest.raises(AmfeError, match="cannot read"):
        load_flagnet(tmp_path / "missing.npz")


def test_a_flag_file_naming_its_network_reads_its_logit(tmp_path):
    flagnet = load_flagnet(_saved(tmp_path, [_net(3)]))
    rng = np.random.default_rng(4)
    n = 300
    fill = rng.random((n, 3, 8, 8))
    bonds = rng.random((n, 3, 8, 8)) * 2.0
    labels = np.exp(rng.normal(size=(n, 6)) * 0.1) + 1.0
    mean = labels * (1 + rng.normal(size=(n, 6)) * 0.06)
    spread = np.full((n, 6), 0.02)
    X = with_flagnet(features(fill, bonds, mean, spread, 1.0), flagnet, fill, bonds)
    assert X.shape[1] == features(fill[:2], bonds[:2], mean[:2], spread[:2], 1.0).shape[1] + 1
    model = fit(X, (mean, labels, spread, fill[:, 0, 0, 0] > 0.5), 1.0)
    model["flagnet"] = "flag_net.npz"
    with open(tmp_path / "flag.json", "w") as f:
        json.dump(model, f)
    loaded = load_flag(tmp_path / "flag.json")
    assert loaded["format_version"] == 2
    assert np.allclose(model_features(loaded, fill, bonds, mean, spread), X)
    one = bed_risk(loaded, fill[0], bonds[0], mean[0], spread[0])
    # one bed alone through the float32 network: the same risk to rounding
    assert one["risk"] == pytest.approx(float(risk(model, X[:1])[0]), rel=1e-5)
    # the network's file gone: a clear error, not a shape mismatch later
    (tmp_path / "flag_net.npz").unlink()
    with pytest.raises(AmfeError, match="error network"):
        load_flag(tmp_path / "flag.json")


def test_a_risk_from_the_network_is_its_logit():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(500, 4))
    labels = np.exp(rng.normal(size=(500, 6)) * 0.1) + 1.0
    data = (labels * (1 + rng.normal(size=(500, 6)) * 0.06), labels, np.full((500, 6), 0.02),
            X[:, 0] > 0)
    model = fit(X, data, 1.0, flag_share=0.2, risk_from="flagnet")
    assert np.array_equal(risk(model, X), X[:, -1])
    assert model["threshold"] == pytest.approx(np.quantile(X[:, -1], 0.8))
    assert abs((risk(model, X) > model["threshold"]).mean() - 0.2) < 0.01
    with pytest.raises(AmfeError, match="logistic"):
        fit(X, data, 1.0, risk_from="spread")


def test_the_shipped_flag_reads_its_network():
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.shipped import models_dir
    flag = load_flag(models_dir() / "flag_small.json")
    assert flag["risk_from"] == "flagnet" and flag["flagnet"] == "flag_small_net.npz"
    ckpt = load_checkpoint(models_dir() / "multiscale_small.pt")
    assert flag["flagnet_net"].image_shape == tuple(ckpt["image_shape"])
    assert len(flag["mu"]) == len(flag["w"]) // 2   # intercept, F features and squares
    # the risk is the network's logit: a bed's risk is exactly that logit (below)
    x = np.random.default_rng(6).random((1,) + tuple(ckpt["image_shape"])).astype(np.float32)
    n = ckpt["arch_args"]["n_fill"]
    one = bed_risk(flag, x[0, :n], x[0, n:], np.array([1e11, 1e11, 1e11, 0.1, 0.1, 0.2]),
                   np.full(6, 0.02))
    # its intervals' scale is the network's b of each constant, not the ensemble's spread
    assert flag["interval_from"] == "flagnet"
    b = np.exp(flag["flagnet_net"].outputs(x)[1][0]) * SCALE
    assert np.allclose([one["interval_scale"][k] for k in LABEL_NAMES], b, rtol=1e-6)
    # it corrects the constants by the network's mu, and its logit is then the centred one
    assert flag["corrects"]
    mu, logb = flag["flagnet_net"].outputs(x)
    assert np.allclose([one["correction"][k] for k in LABEL_NAMES], 1 / (1 + mu[0] * SCALE),
                       rtol=1e-6)
    assert one["risk"] == pytest.approx(float(bad_logit(0 * mu, logb, 0.1)[0]), rel=1e-6)


def _heteroscedastic(rng, n):
    """Beds whose error scale b (the network's logb, SCALE units) is low for half of them
    and high for the rest, and a risk column that knows nothing of it."""
    logb = np.where(rng.random((n, 1)) < 0.5, -1.0, 0.7) * np.ones((1, 6))
    labels = np.exp(rng.normal(size=(n, 6)) * 0.1) + 1.0
    mean = labels * (1 + rng.laplace(0.0, np.exp(logb) * SCALE))
    X = rng.normal(size=(n, 3))
    return X, (mean, labels, np.full((n, 6), 0.02), X[:, 0] > 0), logb


def _coverage(model, X, data, scale):
    from amfe.training.conformal import intervals
    from amfe.training.flagrisk import bins_of
    from amfe.vocab import LABEL_NAMES
    mean, labels = data[0], data[1]
    bins, covered = bins_of(model, X), np.zeros(labels.shape, bool)
    for b, cal in enumerate(model["bins"]):
        rows = bins == b
        lo, hi = intervals(mean[rows], list(LABEL_NAMES), cal, scale[rows])
        covered[rows] = (labels[rows] >= lo) & (labels[rows] <= hi)
    return covered


def test_intervals_scaled_by_the_network_hold_on_each_kind_of_bed():
    from amfe.training.flagrisk import network_scale
    rng = np.random.default_rng(7)
    X, data, logb = _heteroscedastic(rng, 6000)
    by_net = fit(X, data, 1.0, risk_from="flagnet", network={"logb": logb})
    by_spread = fit(X, data, 1.0, risk_from="flagnet")
    assert by_net["interval_from"] == "flagnet" and by_spread["interval_from"] == "spread"
    Xt, test, logbt = _heteroscedastic(rng, 6000)
    low = logbt[:, 0] < 0
    net_cov = _coverage(by_net, Xt, test, network_scale(logbt))
    spread_cov = _coverage(by_spread, Xt, test, test[2])
    for rows in (low, ~low):   # the network's scale: 90 % on the quiet and the noisy beds
        assert np.all(np.abs(net_cov[rows].mean(0) - 0.9) < 0.025)
    # the spread knows nothing of b: the quiet beds over-covered, the noisy ones under
    assert np.all(spread_cov[low].mean(0) > 0.97) and np.all(spread_cov[~low].mean(0) < 0.85)
    # and the network's intervals are narrower on the quiet beds
    assert network_scale(logbt[low]).mean() < network_scale(logbt[~low]).mean() / 4


def test_a_flag_scaling_its_intervals_by_a_network_must_name_it(tmp_path):
    rng = np.random.default_rng(8)
    X, data, logb = _heteroscedastic(rng, 400)
    model = fit(X, data, 1.0, network={"logb": logb})
    with open(tmp_path / "flag.json", "w") as f:
        json.dump(model, f)
    with pytest.raises(AmfeError, match="error network but it names none"):
        load_flag(tmp_path / "flag.json")


def test_the_correction_returns_the_label_the_network_expects():
    from amfe.training.flagrisk import corrected
    rng = np.random.default_rng(9)
    labels = np.concatenate([rng.uniform(5e10, 2e11, (50, 3)), rng.uniform(0.05, 0.3, (50, 3))],
                            axis=1)
    mu = rng.normal(size=(50, 6)) * 2.0    # SCALE units: up to about 20 % off
    predicted = labels * (1 + mu * SCALE)  # r = predicted / label - 1 = mu SCALE exactly
    assert np.allclose(corrected(predicted, mu), labels, rtol=1e-12)
    # a factor per constant: any E (moduli scaled by E / E_model) corrects alike
    assert np.allclose(corrected(3.0 * predicted, mu), 3.0 * labels, rtol=1e-12)


def test_a_bin_with_too_few_calibration_beds_takes_its_risk_bins_quantiles():
    from amfe.training.conformal import calibrate
    from amfe.training.flagrisk import bins_of, network_scale
    rng = np.random.default_rng(10)
    X, data, logb = _heteroscedastic(rng, 2000)
    # beds with skipped pieces are exactly the risky ones: the risky bin of the beds that look
    # whole gets (almost) no calibration beds, too few for a 90 % quantile
    skipped = X[:, -1] > np.quantile(X[:, -1], 0.75)
    model = fit(X, (*data[:3], skipped), 1.0, risk_from="flagnet", network={"logb": logb})
    bins, risk_bins = bins_of(model, X), len(model["bin_edges"]) + 1
    tiny = [b for b in range(len(model["bins"])) if (bins == b).sum() < 9]   # q needs 9
    assert tiny
    for b, cal in enumerate(model["bins"]):
        assert np.all(np.isfinite(list(cal["quantile"].values())))
        if b in tiny:
            rows = bins % risk_bins == b % risk_bins
            pooled = calibrate(data[0][rows], data[1][rows], list(LABEL_NAMES),
                               network_scale(logb[rows]), offset=False)
            assert cal["pooled"] and cal["quantile"] == pooled["quantile"]
        else:
            assert "pooled" not in cal


def test_the_shipped_flag_gives_every_bin_a_finite_interval():
    from amfe.training.shipped import models_dir
    flag = load_flag(models_dir() / "flag_small.json")
    for cal in flag["bins"]:
        assert np.all(np.isfinite(list(cal["quantile"].values())))

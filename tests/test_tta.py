"""Inference: test-time averaging in stacked passes, and the multi-scale net's fast maxima."""

import numpy as np
import pytest
import torch
from test_training import write_synthetic

from amfe.training.checkpoint import load_checkpoint, save_checkpoint
from amfe.training.data import Normalizer, flip_images, transpose_labels
from amfe.training.ensemble import predict_raw, symmetries
from amfe.training.nets import build_net
from amfe.training.train import TrainConfig, train_model
from run.train import merge_members

torch.set_num_threads(1)
SHAPE = (6, 20, 20)


def _net_and_norm(seed=0):
    torch.manual_seed(seed)
    net = build_net("multiscale", SHAPE, {"n_fill": 3, "width": 0.25}).eval()
    rng = np.random.default_rng(seed)
    labels = np.column_stack([rng.uniform(1e10, 2e11, (50, 3)), rng.uniform(0.05, 0.3, (50, 3))])
    return net, Normalizer.fit(labels)


def _one_view_at_a_time(net, norm, x, mode):
    """The TTA mean computed independently: each view alone, mapped back, averaged."""
    outs = []
    with torch.inference_mode():
        for fx, fy, tr in symmetries(mode):
            y = norm.decode(net(flip_images(x, fx, fy, tr)))
            outs.append(transpose_labels(y) if tr else y)
    return torch.stack(outs).mean(dim=0)


@pytest.mark.parametrize("mode", ["none", "flips", "d4"])
def test_stacked_views_equal_views_one_at_a_time(mode):
    net, norm = _net_and_norm()
    x = torch.rand(23, *SHAPE)
    want = _one_view_at_a_time(net, norm, x, mode)
    for batch in (None, 1, 7, 1000):   # chunks of one bed, uneven chunks, one chunk
        got = predict_raw(net, x, norm, mode, batch)
        assert got.shape == (23, 6)
        torch.testing.assert_close(got, want, rtol=1e-5, atol=0)


def test_averaging_differs_from_one_view_and_is_mirror_invariant():
    """A mirror of the input has the same TTA prediction (the mean over the group is invariant)."""
    net, norm = _net_and_norm(1)
    x = torch.rand(9, *SHAPE)
    plain = predict_raw(net, x, norm, "none")
    flips = predict_raw(net, x, norm, "flips")
    assert (flips / plain - 1).abs().max() > 1e-4      # a random net is not mirror invariant
    torch.testing.assert_close(predict_raw(net, x.flip(-1), norm, "flips"), flips,
                               rtol=1e-5, atol=0)
    torch.testing.assert_close(predict_raw(net, x.flip(-2).flip(-1), norm, "flips"), flips,
                               rtol=1e-5, atol=0)
    assert (predict_raw(net, x.flip(-1), norm, "none") / plain - 1).abs().max() > 1e-4


def test_merge_sets_the_averaging_and_calibrates_the_flag_with_it(tmp_path):
    data = str(write_synthetic(tmp_path / "d.h5", shape=(3, 20, 20)))
    parts = []
    for seed in (0, 1):
        cfg = TrainConfig(arch="custom", epochs=1, batch_size=16, members=1, seed=seed)
        path = tmp_path / f"s{seed}.pt"
        save_checkpoint(path, train_model(data, cfg, progress=False, log=lambda line: None))
        parts.append(str(path))
    for tta in ("none", "flips"):
        assert merge_members.main(parts + ["--data", data, "-o", str(tmp_path / f"{tta}.pt"),
                                "--tta", tta]) == 0
    plain, flips = (load_checkpoint(tmp_path / f"{t}.pt") for t in ("none", "flips"))
    assert plain["tta"] == "none" and flips["tta"] == "flips"
    assert plain["members"][0].keys() == flips["members"][0].keys()
    assert all(torch.equal(plain["members"][1][k], flips["members"][1][k])
               for k in plain["members"][1])
    # The flag is calibrated on the averaged predictions: another threshold.
    assert flips["spread"]["threshold"] != plain["spread"]["threshold"]


def _reference_forward(net, x):
    """MultiScaleNet.forward with every stage's maximum taken over its whole map."""
    import torch.nn.functional as F
    holes = 1.0 - x[:, :net.n_fill].amin(dim=1, keepdim=True)
    summaries = []
    for stage, pool in zip(net.stages, net.pool_after):
        x = stage(torch.cat([x, holes], dim=1))
        summaries += [x.mean(dim=(2, 3)), x.amax(dim=(2, 3))]
        if pool:
            x, holes = F.max_pool2d(x, 2), F.max_pool2d(holes, 2)
    return net.head(torch.cat(summaries, dim=1))


@pytest.mark.parametrize("hw", [(20, 20), (21, 19), (6, 10)])
def test_multiscale_maxima_from_the_pooled_maps_are_exact(hw):
    """The stage maxima taken from the 2 x 2 maxima (even maps) are the maps' own, bit for bit,
    and the gradient still reaches the weights."""
    torch.manual_seed(2)
    net = build_net("multiscale", (6, *hw), {"n_fill": 3, "width": 0.25})
    x = torch.rand(5, 6, *hw)
    with torch.no_grad():
        assert torch.equal(net(x), _reference_forward(net, x))
    net(x).sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())

"""Fitting the any-size stiffness network on tiny synthetic beds of two sizes."""
import numpy as np
import torch

from amfe.training.anysize import AnySizeNet
from amfe.training.stiffness import predict_stiffness

# A transversely isotropic C0 [normalised]: unchanged by the mirrors and the x <-> y swap.
C0 = np.array([[4.0, 1.0, 0.8, 0, 0, 0], [1.0, 4.0, 0.8, 0, 0, 0], [0.8, 0.8, 2.5, 0, 0, 0],
               [0, 0, 0, 0.9, 0, 0], [0, 0, 0, 0, 0.9, 0], [0, 0, 0, 0, 0, 1.5]])
SCALE = 1e9


def synthetic(rng, n, cells):
    """Images (n, 1, cells, cells), sizes (n, 2) mm, C (n, 6, 6) Pa growing with fill and size."""
    d = rng.uniform(0.3, 0.8, n)
    x = np.clip(d[:, None, None, None] + 0.05 * rng.standard_normal((n, 1, cells, cells)), 0, 1)
    L = cells * 0.03
    factor = (0.2 + 2.0 * x.mean(axis=(1, 2, 3))) * (1.0 + 2.5 * (L - 0.12))
    return x.astype(np.float32), np.full((n, 2), L), factor[:, None, None] * C0 * SCALE


def test_fit_beats_the_mean_stiffness_at_two_sizes():
    from amfe.training.stiffness_fit import fit_stiffness
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    train = [synthetic(rng, 64, 4), synthetic(rng, 64, 8)]
    test = [synthetic(rng, 32, 4), synthetic(rng, 32, 8)]
    net = AnySizeNet(1, channels=(4, 8), hidden=(32,))
    history = fit_stiffness(net, train, SCALE, epochs=40, lr=5e-3, seed=0)
    assert history[-1] < 0.2 * history[0]
    mean_C = np.concatenate([c for _, _, c in train]).mean(axis=0)
    for x, s, c in test:
        pred = predict_stiffness(net, torch.as_tensor(x), torch.as_tensor(s, dtype=torch.float32),
                                 tta="flips", scale=SCALE)
        assert np.linalg.eigvalsh(pred).min() > 0
        err = np.abs(pred - c)[:, [0, 1, 2], [0, 1, 2]].mean()
        base = np.abs(mean_C - c)[:, [0, 1, 2], [0, 1, 2]].mean()
        assert err < 0.35 * base, (err, base)


def test_stiffness_model_round_trip_and_predict_refuses_it(tmp_path):
    from cli_fixtures import run_main
    from test_training import _tiny_bed

    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.stiffness_fit import load_stiffness_model, stiffness_checkpoint
    torch.manual_seed(2)
    args = {"layers_in": 1, "channels": (4, 8), "hidden": (16,)}
    net = AnySizeNet(**args)
    px = {"image_cell": [30e-6, 30e-6], "layer_thickness": 0.1e-3, "image_spacing": 2.5e-6}
    path = save_checkpoint(tmp_path / "c.pt", stiffness_checkpoint(net, args, SCALE, px, 1))
    back, ckpt = load_stiffness_model(path)
    x = torch.rand(3, 1, 6, 6)
    s = torch.full((3, 2), 0.18)
    np.testing.assert_array_equal(predict_stiffness(back, x, s, scale=ckpt["stiffness_scale"]),
                                  predict_stiffness(net, x, s, scale=SCALE))
    bed = _tiny_bed(tmp_path / "bed.h5")
    code, out, err = run_main(["predict", bed, "--model", path])
    assert code == 2 and "not a plain amfe checkpoint" in err and len(err.strip().splitlines()) == 1

"""Numpy inference of the multi-scale network (training/npnet.py) and the torch-free reader of
checkpoints (training/torchfile.py): the same numbers as torch, the same refusals, no torch.
"""
import pickle
import subprocess
import sys
from collections import OrderedDict

import numpy as np
import pytest
import torch

from amfe.errors import AmfeError
from amfe.training.checkpoint import load_checkpoint, save_checkpoint
from amfe.training.ensemble import predict_raw, symmetries
from amfe.training.multiscale import MultiScaleNet
from amfe.training.npnet import NumpyMultiScale, multiscale_shapes
from amfe.training.npnet import predict_raw as predict_numpy
from amfe.training.predict import Surrogate
from amfe.training.shipped import models_dir
from amfe.training.torchfile import TensorArray, read_torch_file

# (image shape, arch args): the shipped small model's, a thin odd-sized one (poolings
# skipped below 2 x 2, odd maps pooled with floor), the anybed network's descriptor planes
CASES = [((6, 20, 20), {"n_fill": 3, "width": 0.5}),
         ((2, 7, 5), {"width": 0.25, "hidden": [16, 8]}),
         ((15, 12, 12), {"n_fill": 6, "width": 0.25, "features": 3, "hidden": [32]}),
         ((6, 20, 20), {"n_fill": 2, "features": 2, "channels": [6, 10, 12], "hidden": [8]})]


def _random_net(shape, args, seed, std=0.3):
    torch.manual_seed(seed)
    net = MultiScaleNet(shape, **{**args, "hidden": tuple(args.get("hidden", (512, 256, 128)))})
    with torch.no_grad():   # biases too, so that a wrong order of terms shows
        for p in net.parameters():
            p.normal_(0.0, std)
    return net.eval()


@pytest.mark.parametrize("shape,args", CASES)
def test_numpy_forward_is_torchs(shape, args):
    net = _random_net(shape, args, 1)
    assert multiscale_shapes(shape, **args) == {k: tuple(v.shape)
                                                for k, v in net.state_dict().items()}
    x = np.random.default_rng(2).random((9, *shape)).astype(np.float32)
    if args.get("features"):      # descriptor planes are constant per bed
        x[:, -args["features"]:] = x[:, -args["features"]:, :1, :1]
    with torch.no_grad():
        want = net(torch.from_numpy(x)).numpy()
    state = {k: v.numpy() for k, v in net.state_dict().items()}
    got = NumpyMultiScale(state, shape, args)(x)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())


def test_numpy_tta_is_torchs():
    """The symmetries, decoding and label transposes of predict_raw, d4 included."""
    from amfe.training.data import Normalizer
    shape, args = CASES[0]
    net = _random_net(shape, args, 3, std=0.02)   # outputs of order 1: no exp overflow
    norm = {"mean": [26.0, 26.0, 26.0, 0.1, 0.1, 0.2], "std": [0.3, 0.3, 0.3, 0.02, 0.02, 0.05],
            "log": [True, True, True, False, False, False]}
    x = np.random.default_rng(4).random((5, *shape)).astype(np.float32)
    state = {k: v.numpy() for k, v in net.state_dict().items()}
    for mode in ("none", "flips", "d4"):
        want = predict_raw(net, torch.from_numpy(x), Normalizer.from_dict(norm), mode).numpy()
        got = predict_numpy(NumpyMultiScale(state, shape, args), x, norm,
                            symmetries(mode, True), batch_size=16)
        np.testing.assert_allclose(got, want, rtol=2e-5)


@pytest.mark.parametrize("name", ["multiscale_small.pt", "anybed_small.pt",
                                  "multiscale_small_continuum.pt", "thick_2layers.pt",
                                  "thick_5layers.pt"])
def test_shipped_models_predict_the_same_in_numpy(name):
    numpy_, torch_ = (Surrogate.load(models_dir() / name, backend=b) for b in ("numpy", "torch"))
    assert (numpy_.backend, torch_.backend) == ("numpy", "torch")
    x = np.random.default_rng(5).random((6, *numpy_.image_shape)).astype(np.float32)
    a, b = numpy_.member_outputs(x), torch_.member_outputs(x)
    np.testing.assert_allclose(a, b, rtol=1e-5)


def test_stiffness_models_stay_on_torch():
    sur = Surrogate.load(models_dir() / "stiffness_small.pt")
    assert sur.backend == "torch"
    with pytest.raises(AmfeError, match="numpy backend runs six-constant multiscale"):
        Surrogate.load(models_dir() / "stiffness_small.pt", backend="numpy")
    with pytest.raises(AmfeError, match="backend must be one of"):
        Surrogate.load(models_dir() / "multiscale_small.pt", backend="jax")


def test_reader_gives_torch_loads_tensors(tmp_path):
    """Dtypes, views with offsets and strides into one storage, nesting, OrderedDict."""
    base = torch.arange(24, dtype=torch.float64).reshape(4, 6)
    obj = {"a": base, "t": base.t(), "row": base[2], "col": base[:, 3],
           "empty": torch.zeros(0, 3), "f": torch.linspace(0, 1, 7, dtype=torch.float32),
           "i": torch.tensor([1, -2], dtype=torch.int64), "b": torch.tensor([True, False]),
           "h": torch.ones(3, dtype=torch.float16),
           "od": OrderedDict([("z", torch.ones(2)), ("y", [1, 2.5, "s", None])]), "n": 3}
    torch.save(obj, tmp_path / "x.pt")
    got = read_torch_file(tmp_path / "x.pt")
    assert list(got) == list(obj) and isinstance(got["od"], OrderedDict)
    for k in ("a", "t", "row", "col", "empty", "f", "i", "b", "h"):
        assert isinstance(got[k], TensorArray) and got[k].dtype == obj[k].numpy().dtype
        np.testing.assert_array_equal(got[k], obj[k].numpy())
    assert got["od"]["y"] == [1, 2.5, "s", None] and got["n"] == 3


class _Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_reader_refuses_code_and_never_runs_it(tmp_path):
    marker = tmp_path / "ran"
    torch.save({"format": "amfe.surrogate", "x": _Payload(str(marker))}, tmp_path / "evil.pt")
    with pytest.raises(pickle.UnpicklingError, match="not plain data"):
        read_torch_file(tmp_path / "evil.pt")
    with pytest.raises(AmfeError, match="refuses to load.*pickled Python objects"):
        load_checkpoint(tmp_path / "evil.pt", arrays=True)
    assert not marker.exists()
    (tmp_path / "bare.pt").write_bytes(pickle.dumps(_Payload(str(marker))))
    with pytest.raises(AmfeError, match="pickled Python objects"):
        load_checkpoint(tmp_path / "bare.pt", arrays=True)
    assert not marker.exists()


def test_a_checkpoint_read_without_torch_saves_back_the_same(tmp_path):
    path = models_dir() / "multiscale_small.pt"
    ck = load_checkpoint(path, arrays=True)
    save_checkpoint(tmp_path / "again.pt", ck)
    back, ref = (torch.load(p, weights_only=True) for p in (tmp_path / "again.pt", path))
    for a, b in zip(back["members"], ref["members"]):
        assert list(a) == list(b)
        assert all(isinstance(a[k], torch.Tensor) and torch.equal(a[k], b[k]) for k in b)
    assert back["normalizer"] == ref["normalizer"] and back["conformal"] == ref["conformal"]


def test_predicting_a_shipped_bed_imports_no_torch(tmp_path):
    """The point of it all: amfe.predict (and amfe predict, amfe sweep's surrogate rows, which
    call the same records) of a small bed starts without torch's 2.5-4 s import."""
    from amfe.io.bedfile import write_bed
    from amfe.model.scales import bed_for
    bed = tmp_path / "small.h5"
    write_bed(bed, bed_for("small", 3))
    code = (f"import sys, amfe; r = amfe.predict({str(bed)!r}); "
            "assert 'torch' not in sys.modules, 'torch imported'; "
            "print(r.properties['Ex'], r.intervals['Ex'])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    ex, lo_hi = proc.stdout.split(" ", 1)
    import amfe
    want = amfe.predict(str(bed))
    assert abs(float(ex) / want.properties["Ex"] - 1) < 1e-5

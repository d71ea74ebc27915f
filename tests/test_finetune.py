"""Fine-tuning from a trained checkpoint (`amfe train --init`, training/finetune.py)."""
import argparse

import h5py
import numpy as np
import pytest
import torch
from test_training import write_synthetic

from amfe.errors import AmfeError
from amfe.training.checkpoint import load_checkpoint, save_checkpoint
from amfe.training.data import Normalizer, read_rows
from amfe.training.merge import merge_members
from amfe.training.predict import Surrogate
from amfe.training.train import TrainConfig, train_model

torch.set_num_threads(1)
QUIET = {"progress": False, "log": lambda line: None}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A 2-member LeNet-5 trained on one synthetic data set, and a second data set."""
    d = tmp_path_factory.mktemp("finetune")
    first = str(write_synthetic(d / "a.h5", seed=0))
    second = str(write_synthetic(d / "b.h5", n=50, seed=1, failed=()))
    ckpt = train_model(first, TrainConfig(arch="lenet5", epochs=2, batch_size=16, members=2,
                                          seed=3, log_poisson="nu_xy"), **QUIET)
    path = d / "base.pt"
    save_checkpoint(path, ckpt)
    return {"path": str(path), "ckpt": load_checkpoint(path), "first": first, "second": second}


def _tune(base, **kw):
    cfg = TrainConfig(**{"epochs": 1, "batch_size": 16, "seed": 7, "init": base["path"], **kw})
    return train_model(base["second"], cfg, **QUIET)


def test_a_member_starts_from_the_checkpoint_and_keeps_its_normalisation(base):
    """At a vanishing learning rate the tuned member predicts as the member it started from
    (a fresh network would not), in the initial model's label normalisation (the new data
    would give another one), with its network and log flags though none was asked for."""
    tuned = _tune(base, init_member=1, lr=1e-12)
    assert tuned["arch"] == "lenet5" and tuned["normalizer"] == base["ckpt"]["normalizer"]
    assert tuned["training"]["log_poisson"] == ["nu_xy"] or \
        tuned["training"]["log_poisson"] == ("nu_xy",)
    _, labels = read_rows(base["second"])
    refit = Normalizer.fit(labels, log=(True,) * 3 + (False, False, True)).to_dict()
    assert not np.allclose(refit["mean"], tuned["normalizer"]["mean"])
    images, _ = read_rows(base["second"])
    start = Surrogate(base["ckpt"], "base").member_outputs(images)[1]
    after = Surrogate(tuned, "tuned").member_outputs(images)[0]
    np.testing.assert_allclose(after, start, rtol=1e-6)
    fresh = _tune(dict(base, path=""), arch="lenet5", lr=1e-12, log_poisson="nu_xy")
    assert np.abs(Surrogate(fresh, "fresh").member_outputs(images)[0] / start - 1).max() > 1e-3
    init = tuned["init"]
    assert init["member"] == 1 and init["member_seeds"] == [4] and init["path"] == base["path"]
    assert init["dataset"]["sha256"] == base["ckpt"]["dataset"]["sha256"]
    lo, hi = tuned["fill_range"]["lo"], tuned["fill_range"]["hi"]
    assert lo <= base["ckpt"]["fill_range"]["lo"] and hi >= base["ckpt"]["fill_range"]["hi"]


def test_fine_tuning_lowers_the_loss_on_the_new_data(base):
    tuned = _tune(base, epochs=6, lr=1e-3, val_fraction=0.0)
    loss = tuned["history"][0]["train_loss"]
    assert loss[-1] < loss[0]


def test_tuned_members_merge_and_record_where_they_started(base, tmp_path):
    parts = []
    for member, seed in ((1, 8), (0, 7)):
        path = tmp_path / f"m{member}.pt"
        save_checkpoint(path, _tune(base, init_member=member, seed=seed))
        parts.append(load_checkpoint(path))
    merged = merge_members(parts, base["second"])
    assert merged["member_seeds"] == [7, 8]
    assert merged["init"]["member"] == [0, 1] and merged["init"]["member_seeds"] == [3, 4]
    plain = train_model(base["second"], TrainConfig(arch="lenet5", epochs=1, batch_size=16,
                                                    seed=9, log_poisson="nu_xy"), **QUIET)
    plain["normalizer"] = parts[0]["normalizer"]   # only the origin differs
    with pytest.raises(AmfeError, match="fine-tuned from another model"):
        merge_members([parts[0], plain], base["second"])


def test_bad_starting_points_are_refused(base, tmp_path):
    with pytest.raises(AmfeError, match="has 2 member"):
        _tune(base, init_member=1, members=2)
    other = str(write_synthetic(tmp_path / "other.h5", shape=(2, 20, 20)))
    with pytest.raises(AmfeError, match="other.h5"):
        train_model(other, TrainConfig(epochs=1, init=base["path"]), **QUIET)
    tiny = str(write_synthetic(tmp_path / "tiny.h5", attrs={
        "scale": "small", "bed_size": [0.3e-3, 0.6e-3, 0.3e-3],
        "image_cell": [30e-6, 30e-6, 0.1e-3],
        "layer_thickness": 0.1e-3, "image_spacing": 2.5e-6}))
    with pytest.raises(AmfeError, match="bed_size"):
        train_model(tiny, TrainConfig(epochs=1, init=base["path"]), **QUIET)
    negative = str(write_synthetic(tmp_path / "negative.h5", failed=()))
    with h5py.File(negative, "r+") as f:   # the base model takes nu_xy's logarithm
        f["labels"][:, 5] = -0.01
    with pytest.raises(AmfeError, match=r"logarithms.*nu_xy \(min -0.01\)"):
        train_model(negative, TrainConfig(epochs=1, init=base["path"], val_fraction=0.0), **QUIET)


def test_cli_refuses_network_options_with_init(base):
    from amfe.cli.train import DEFAULTS, NETWORK_OPTIONS, check_init_options
    args = argparse.Namespace(**NETWORK_OPTIONS, init=base["path"], init_member=0)
    check_init_options(args)
    for key, value in (("arch", "vgg"), ("width", 0.5), ("log_poisson", "nu_xy")):
        with pytest.raises(AmfeError, match="--" + key.replace("_", "-")):
            check_init_options(argparse.Namespace(**dict(vars(args), **{key: value})))
    with pytest.raises(AmfeError, match="needs --init"):
        check_init_options(argparse.Namespace(**dict(vars(args), init=None, init_member=1)))
    assert NETWORK_OPTIONS["arch"] == DEFAULTS.arch

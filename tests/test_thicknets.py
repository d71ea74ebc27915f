"""Networks of one thickness (issue 46, amfe.training.thicknets): their input, the check that
a checkpoint is the thickness it is installed for, and the shipped 2-layer network."""
import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.training.thicknets import THICK_FILES, check_thick, load_thick, thick_inputs


def test_the_input_is_the_beds_layers_then_nu_and_psi_as_planes():
    rng = np.random.default_rng(0)
    fill, bonds = rng.random((3, 2, 5, 4)), rng.random((3, 2, 5, 4))
    nu, psi = np.array([0.28, 0.25, 0.4]), np.array([0.08, 0.04, 0.12])
    x = thick_inputs(fill, bonds, nu, psi)
    assert x.shape == (3, 6, 5, 4) and x.dtype == np.float32
    np.testing.assert_array_equal(x[:, :2], fill.astype(np.float32))
    np.testing.assert_array_equal(x[:, 2:4], bonds.astype(np.float32))
    # the anybed descriptors' scale: zero at the paper's steel
    np.testing.assert_allclose(x[:, 4], ((nu - 0.28) / 0.1)[:, None, None] + np.zeros((5, 4)),
                               atol=1e-6)
    np.testing.assert_allclose(x[:, 5], ((psi - 0.08) / 0.04)[:, None, None] + np.zeros((5, 4)),
                               atol=1e-6)


def test_a_checkpoint_of_another_thickness_is_refused():
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import models_dir
    with pytest.raises(AmfeError, match="is not a network of 2 layers"):
        check_thick(Surrogate.load(models_dir() / "anybed_small.pt"), 2)


def test_the_shipped_networks_are_of_their_thickness_and_unseen_by_the_stack():
    """Each installed network says its thickness, reads (2 L + 2)-plane inputs and was trained
    on records the stack's fitting beds leave out (their ranges do not meet)."""
    import json

    from amfe.training.anystack import STACK_FILE
    from amfe.training.shipped import models_dir
    thick = load_thick()
    assert sorted(thick) == sorted(THICK_FILES)
    stack = json.loads((models_dir() / STACK_FILE).read_text())
    for layers, sur in thick.items():
        assert sur.image_shape[0] == 2 * layers + 2 and sur.n_members == 2
        trained = _records(sur.ckpt["thick"]["data"])
        fitted = _records([f"{d['data_set']}:{d['records']}" for d in stack["data"]
                           if d["scale"].startswith(f"box600x600x{layers}00um")])
        assert fitted and trained and not trained & fitted


def _records(specs, n=100_000):
    """The record positions (below n) that PATH:A-B,C-D specs of one data set select."""
    from run.common import record_spec
    return {int(k) for spec in specs for k in np.flatnonzero(record_spec(spec)[1](np.arange(n)))}


def test_turning_a_bed_upside_down_reverses_its_layers_and_keeps_the_planes():
    from amfe.training.thicknets import upside_down
    assert upside_down(3, 8) == [2, 1, 0, 5, 4, 3, 6, 7]
    order = upside_down(5, 12)
    assert [order[i] for i in order] == list(range(12))      # an involution


def test_the_training_symmetries_carry_their_labels():
    """Each sample of an augmented batch is one of the 16 symmetries of its bed (mirrors in x
    and y, upside down, x <-> y), and its labels are the bed's, permuted where x and y swap
    (amfe.training.data.transpose_labels); mirrored or turned beds keep theirs."""
    import torch

    from amfe.training.data import transpose_labels
    from amfe.training.thicknets import upside_down
    from run.train.train_thick import augment
    layers, n = 2, 64
    x = torch.as_tensor(np.random.default_rng(1).random((n, 2 * layers + 2, 5, 5)),
                        dtype=torch.float32)
    y = torch.as_tensor(np.random.default_rng(2).random((n, 6)) + 0.2, dtype=torch.float64)
    t = y.log()
    mean, std = t.mean(0).numpy(), t.std(0).numpy()
    z = ((t - torch.as_tensor(mean)) / torch.as_tensor(std)).float()
    xb, zb = augment(x, z, layers, "d4z", (mean, std), np.random.default_rng(3))
    yb = torch.exp(zb.double() * torch.as_tensor(std) + torch.as_tensor(mean))
    seen = set()
    for i in range(n):
        matches = []
        for fx, fy, down, tr in np.ndindex(2, 2, 2, 2):
            v = x[i:i + 1, upside_down(layers, x.shape[1])] if down else x[i:i + 1]
            v = v.flip(3) if fx else v
            v = v.flip(2) if fy else v
            v = v.transpose(2, 3) if tr else v
            if torch.equal(v, xb[i:i + 1]):
                matches.append((fx, fy, down, tr))
        assert len(matches) == 1
        seen.add(matches[0])
        want = transpose_labels(y[i:i + 1]) if matches[0][3] else y[i:i + 1]
        torch.testing.assert_close(yb[i:i + 1], want, rtol=1e-5, atol=0)
    assert len(seen) > 8     # the batch holds many of the 16


def test_a_network_trained_both_ways_up_reads_a_bed_as_its_upside_down_twin():
    """The 5-layer network learned beds turned over too (and x <-> y swapped): it averages a
    bed with its upside-down twin, so the twin gets the same six constants (an exact
    invariance, to float32 rounding)."""
    from amfe.training.thicknets import thick_members
    thick = load_thick()
    assert thick[5].ckpt["thick"]["augment"] == "d4z"
    rng = np.random.default_rng(4)
    fill = rng.random((3, 5, 20, 20)).astype(np.float32) * 0.6
    bonds = rng.random((3, 5, 20, 20)).astype(np.float32) * 0.3
    nu, psi = np.array([0.28, 0.3, 0.35]), np.array([0.08, 0.1, 0.05])
    models = {"thick": thick}
    out = thick_members(models, fill, bonds, nu, psi)
    np.testing.assert_allclose(thick_members(models, fill[:, ::-1], bonds[:, ::-1], nu, psi),
                               out, rtol=2e-5)
    # and not by construction of the test: one way up alone differs
    one_way = thick[5].run_members(thick_inputs(fill, bonds, nu, psi))
    assert np.max(np.abs(one_way / out - 1)) > 1e-4


def test_training_leaves_out_a_bed_with_a_non_positive_constant(monkeypatch, capsys):
    """A bed with a negative Poisson ratio (one in 19 000 of the 5-layer set) has no log: it is
    left out of training with a line that says so, not turned into a NaN loss."""
    import run.train.train_thick as tt
    rng = np.random.default_rng(4)
    fill, bonds = rng.random((3, 2, 5, 4)), rng.random((3, 2, 5, 4))
    y = rng.random((3, 6)) + 0.1
    y[1, 4] = -0.05
    nu, psi = np.full(3, 0.28), np.full(3, 0.08)
    monkeypatch.setattr(tt, "read_unseen", lambda spec: (fill, bonds, y, nu, psi))
    x, labels, layers = tt.read_sets(["set.h5"])
    assert layers == 2 and len(x) == 2
    np.testing.assert_array_equal(labels, y[[0, 2]])
    np.testing.assert_array_equal(x, thick_inputs(fill, bonds, nu, psi)[[0, 2]])
    assert "leaving out 1 of 3 beds" in capsys.readouterr().out
    y[:, 0] = 0.0
    with pytest.raises(SystemExit, match="every bed has a non-positive constant"):
        tt.read_sets(["set.h5"])


def test_members_trained_under_another_augmentation_are_not_joined(monkeypatch):
    """The joined network's ``augment`` decides whether it reads a bed both ways up, so a part
    trained otherwise than the joining command says is refused, not relabelled."""
    import amfe.training.checkpoint as checkpoint
    from run.common import join_members
    part = {"thick": {"data": ["L5.h5"], "augment": "d4z", "seconds": 1.0},
            "members": [{}], "history": [[]], "member_seeds": [0]}
    monkeypatch.setattr(checkpoint, "load_checkpoint", lambda path: part)
    states, _, seeds, seconds, _ = join_members(["p0.pt", "p1.pt"], ["L5.h5"], "thick",
                                                agree={"augment": "d4z"})
    assert len(states) == 2 and seconds == 2.0
    with pytest.raises(SystemExit, match="p0.pt was trained with --augment d4z, not --augment "
                                         "flips"):
        join_members(["p0.pt"], ["L5.h5"], "thick", agree={"augment": "flips"})

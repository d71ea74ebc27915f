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

"""The anybed stack (issue 46): thick beds read through their 3-layer windows, and the anybed
route's intervals per thickness (amfe.training.anystack, docs/surrogate.md, "Any bed").

Checks against what must hold exactly or by construction: a stack whose coefficients
pick log d_k gives the network's members bit for bit; the fit recovers a known log-linear
map; cross-fitted predictions never see their own bed; a stack fitted to another network
is refused; a thick bed's windows are its consecutive 3-layer sub-stacks as the network
reads them; the shipped stack is the network's and holds every thickness it routes.
"""
import json

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.training.anybed import anybed_inputs
from amfe.training.anystack import (
    EXTRA_READS,
    FORMAT,
    FORMAT_VERSION,
    Reads,
    cross_fitted,
    design,
    fit,
    image_means,
    layer_entry,
    load_stack,
    n_columns,
    stack,
    window_starts,
)


def _outputs(rng, m=2, n=40, w=3):
    direct = np.exp(rng.normal(0, 0.3, (m, n, 6))) * [1e11, 1e11, 1e11, 0.05, 0.05, 0.1]
    windows = direct[:, None] * np.exp(rng.normal(0, 0.05, (m, w, n, 6)))
    nu, psi = rng.uniform(0.25, 0.4, n), rng.uniform(0.04, 0.12, n)
    means = rng.uniform(0.3, 0.9, (n, 2 * (w + 2) + 2))
    return direct, windows, nu, psi, means


def test_a_stack_that_reads_log_d_gives_the_members_bit_for_bit():
    direct, windows, nu, psi, means = _outputs(np.random.default_rng(0))
    p = design(0, direct[0], windows[0], nu, psi, means).shape[1]
    layers = windows.shape[1] + 2
    assert p == n_columns(layers) - EXTRA_READS.get(layers, 0)   # no extra reads given here
    coefs = np.zeros((6, p))
    coefs[:, 1] = 1.0          # column 1 is log d_k
    np.testing.assert_allclose(stack(coefs, Reads(direct, windows, nu, psi, means)), direct,
                               rtol=1e-14)
    coefs = np.zeros((6, design(0, direct[0], None, nu, psi, means).shape[1]))
    coefs[:, 1] = 1.0
    thin = stack(coefs, Reads(direct, None, nu, psi, means))
    np.testing.assert_allclose(thin, direct, rtol=1e-14)   # 2 layers: no window columns


def test_a_three_layer_stack_can_take_the_small_models_geometry_and_the_networks_material():
    """With steel = (small model s, network at steel r), the coefficients 1, 1, -1 on log d_k,
    log s_k, log r_k give s d / r member by member: the last two columns are those."""
    rng = np.random.default_rng(4)
    direct, _, nu, psi, means = _outputs(rng, w=1)
    steel = direct[None] * np.exp(rng.normal(0, 0.1, (2,) + direct.shape))
    p = n_columns(3)
    assert p == design(0, direct[0], None, nu, psi, means, steel[:, 0]).shape[1]
    assert p == design(0, direct[0], None, nu, psi, means).shape[1] + 2   # log s_k, log r_k
    coefs = np.zeros((6, p))
    coefs[:, 1], coefs[:, -2], coefs[:, -1] = 1.0, 1.0, -1.0
    got = stack(coefs, Reads(direct, None, nu, psi, means, steel))
    np.testing.assert_allclose(got, direct * steel[0] / steel[1], rtol=1e-12)


def test_the_fit_recovers_a_known_map_and_cross_fitting_holds_each_bed_out():
    rng = np.random.default_rng(1)
    direct, windows, nu, psi, means = _outputs(rng, m=1, n=400)
    # labels: the windows' mean, 3 % up, and a nu dependence the network missed
    truth = np.exp(np.log(windows[0]).mean(axis=0)) * 1.03 * np.exp(0.5 * (nu - 0.3))[:, None]
    reads = Reads(direct, windows, nu, psi, means)
    coefs = fit(reads, truth, ridge=1e-12)
    got = stack(coefs, reads)[0]
    np.testing.assert_allclose(got, truth, rtol=1e-8)
    assert np.allclose(coefs[:, 2], 1.0) and np.allclose(coefs[:, 1], 0.0, atol=1e-8)
    # a bed's cross-fitted value is unchanged when its own label is changed
    moved = truth.copy()
    moved[7] *= 5.0
    a = cross_fitted(reads, truth)
    b = cross_fitted(reads, moved)
    assert np.array_equal(a[:, 7], b[:, 7])
    assert not np.allclose(a, b)


def test_a_non_positive_output_keeps_the_beds_own_members():
    direct, windows, nu, psi, means = _outputs(np.random.default_rng(2))
    direct[1, 3, 5] = -0.01
    coefs = np.zeros((6, design(0, direct[0], windows[0], nu, psi, means).shape[1]))
    out = stack(coefs, Reads(direct, windows, nu, psi, means))
    assert np.array_equal(out[:, 3], direct[:, 3])
    assert np.allclose(out[:, 4], 1.0)
    with pytest.raises(AmfeError, match="positive"):
        fit(Reads(direct, windows, nu, psi, means), np.abs(direct[0]))


def test_windows_are_the_consecutive_three_layer_stacks_as_the_network_reads_them():
    assert window_starts(2) == window_starts(3) == []
    assert window_starts(5) == [0, 1, 2]
    rng = np.random.default_rng(3)
    fill, bonds = rng.random((2, 5, 4, 4)), rng.random((2, 5, 4, 4))
    x = anybed_inputs(fill[:, 1:4], bonds[:, 1:4], [0.3, 0.3], [0.08, 0.08])
    assert np.array_equal(x[:, :3], fill[:, 1:4].astype(np.float32))
    assert np.all(x[:, 3:6] == 1.0)                      # absent fill layers: full
    m = image_means(fill, bonds)
    assert m.shape == (2, 12)
    np.testing.assert_allclose(m[:, 10], fill.mean(axis=(2, 3)).min(axis=1))


def test_a_stack_fitted_to_another_network_is_refused(tmp_path):
    path = tmp_path / "stack.json"
    assert load_stack(path, "2026-12-05T00:00:00+00:00") is None      # none installed
    path.write_text(json.dumps({"format": FORMAT, "format_version": FORMAT_VERSION,
                                "network_created": "A", "layers": {}}))
    with pytest.raises(AmfeError, match="refit"):
        load_stack(path, "B")
    assert layer_entry(load_stack(path, "A"), 5) is None
    path.write_text(json.dumps({"format": FORMAT, "format_version": FORMAT_VERSION,
                                "network_created": "A",
                                "layers": {"5": {"coefs": [[0.0] * 9] * 6, "calibration": {}}}}))
    with pytest.raises(AmfeError, match=rf"\(6, 9\), not \(6, {n_columns(5)}\): refit"):
        layer_entry(load_stack(path, "A"), 5)
    path.write_text("{")
    with pytest.raises(AmfeError, match="not a readable anybed stack"):
        load_stack(path, "A")


def test_a_missing_stack_is_an_error_not_the_network_alone(tmp_path, monkeypatch):
    import amfe.training.anypredict as anypredict
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import models_dir
    anybed = Surrogate.load(models_dir() / "anybed_small.pt")
    monkeypatch.setattr(anypredict, "models_dir", lambda: tmp_path)
    with pytest.raises(AmfeError, match="anybed_stack.json is not installed; reinstall"):
        anypredict.load_stack_for(anybed, {})


def test_a_stack_fitted_to_other_networks_of_one_thickness_is_refused():
    from amfe.training.anypredict import load_stack_for
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import models_dir
    from amfe.training.thicknets import load_thick
    anybed, thick = Surrogate.load(models_dir() / "anybed_small.pt"), load_thick()
    assert load_stack_for(anybed, thick) is not None
    with pytest.raises(AmfeError, match="fitted to the networks of one thickness"):
        load_stack_for(anybed, {})


def test_a_two_layer_stack_can_take_the_two_layer_networks_reading():
    """At 2 layers the extra read is the 2-layer network t: coefficient 1 on its column
    (the last) and 0 elsewhere gives t member by member."""
    rng = np.random.default_rng(5)
    direct, _, nu, psi, means = _outputs(rng, w=0)
    own = direct[None] * np.exp(rng.normal(0, 0.1, (1,) + direct.shape))
    p = n_columns(2)
    assert p == design(0, direct[0], None, nu, psi, means).shape[1] + 1   # log t_k
    coefs = np.zeros((6, p))
    coefs[:, -1] = 1.0
    got = stack(coefs, Reads(direct, None, nu, psi, means, own))
    np.testing.assert_allclose(got, own[0], rtol=1e-12)


def test_the_shipped_stack_is_the_networks_and_calibrated_per_thickness():
    from amfe.training.anypredict import load_stack_for
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import models_dir
    from amfe.training.thicknets import load_thick
    anybed = Surrogate.load(models_dir() / "anybed_small.pt")
    data = load_stack_for(anybed, load_thick())
    assert data is not None
    for layers in (2, 3, 4, 5, 6):
        entry = layer_entry(data, layers)
        assert entry is not None, layers
        cal = entry["calibration"]
        assert cal["uses_spread"] and cal["n"] >= 300
        assert all(np.isfinite(v) and v > 0 for v in cal["quantile"].values())
        # the stack was kept because it beat the network on its cross-fitted beds
        raw = data["layers"][str(layers)]
        assert (np.mean(list(raw["mre_stack_cross_fitted"].values()))
                < np.mean(list(raw["mre_network"].values())))


def _by_hand(layers):
    """(amfe.predict's record, the stack's constants computed step by step) of a drawn-material
    bed of ``layers`` layers: the network on the bed and its windows and, at 3 layers, the
    small model and the network at steel's nu and psi, at 2 the 2-layer network (5 layers is
    not built here)."""
    import amfe
    from amfe.model.scales import bed_for, record_seed
    from amfe.training.anypredict import _members, bed_images, load_stack_for
    from amfe.training.predict import Surrogate
    from amfe.training.shipped import models_dir
    from amfe.training.thicknets import load_thick, thick_inputs
    bed = bed_for(f"box600x600x{layers}00um_nu250to400psi40to120", record_seed(7, 0))
    p = amfe.predict(bed).to_dict()
    anybed, thick = Surrogate.load(models_dir() / "anybed_small.pt"), load_thick()
    entry = layer_entry(load_stack_for(anybed, thick), layers)
    fill, bonds, _ = bed_images(bed, bed.attrs["size"])
    nu = np.array([float(bed.attrs["material_nu"])])
    psi = np.array([float(bed.attrs["material_psi"])])
    f, b = fill[None], bonds[None]
    direct = _members(anybed, anybed_inputs(f, b, nu, psi))
    windows = None if layers < 4 else np.stack(
        [_members(anybed, anybed_inputs(f[:, s:s + 3], b[:, s:s + 3], nu, psi))
         for s in range(layers - 2)], axis=1)
    extra = None
    if layers == 3:
        small = Surrogate.load(models_dir() / "multiscale_small.pt")
        extra = np.stack([_members(small, np.concatenate([f, b], axis=1)),
                          _members(anybed, anybed_inputs(f, b, [0.28], [0.08]))])
    elif layers == 2:
        extra = _members(thick[2], thick_inputs(f, b, nu, psi))[None]
    want = stack(entry["coefs"], Reads(direct, windows, nu, psi, image_means(f, b), extra))
    want = want.mean(axis=0)[0]
    want[:3] *= float(bed.attrs["material_E"]) / 210e9
    return bed, p, want


def _constants(p):
    return np.array([p["properties"][k] for k in ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy")])


def test_a_thick_bed_is_predicted_through_its_windows_as_the_stack_says(tmp_path):
    """amfe.predict and the CLI give, for a 4-layer bed, the stack of the network's members on
    the bed and on its two windows, computed here step by step."""
    from helpers import run_cli

    import amfe
    bed, p, want = _by_hand(4)
    assert p["route"] == "anybed" and any("3-layer windows" in n for n in p["notes"])
    np.testing.assert_allclose(_constants(p), want, rtol=1e-6)
    path = tmp_path / "thick.h5"
    amfe.write_bed(str(path), bed)
    out = tmp_path / "p.json"
    proc = run_cli(["predict", str(path), "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    assert json.loads(out.read_text())["beds"][0]["properties"] == p["properties"]


def test_a_three_layer_alloy_bed_is_read_by_the_small_model_too_as_the_stack_says():
    """A 3-layer bed of another nu and psi: the stack of the network's members, the small
    model's and the network's at steel's nu and psi, computed here step by step."""
    _, p, want = _by_hand(3)
    assert p["route"] == "anybed"
    np.testing.assert_allclose(_constants(p), want, rtol=1e-6)


def test_a_two_layer_bed_is_read_by_the_two_layer_network_too_as_the_stack_says():
    """A 2-layer bed: the stack of the network's members and the 2-layer network's,
    computed here step by step; the record says so."""
    _, p, want = _by_hand(2)
    assert p["route"] == "anybed" and any("2-layer network" in n for n in p["notes"])
    np.testing.assert_allclose(_constants(p), want, rtol=1e-6)

"""The surrogate's input for any thickness and material: ``anybed`` (issue 46).

One network reads beds of 2 to 6 powder layers and of any nu and psi in the
trained ranges. Its input (docs/surrogate.md, "Any bed") is the data set's
image stack padded to :data:`MAX_LAYERS` layers, then the bed's descriptors as
constant planes (:class:`amfe.training.multiscale.MultiScaleNet` with
``features``: the head reads their means beside the image's summaries):

- fill layers 0..n-1 (bottom first), then fill 1.0 for the absent layers
  n..5 (full: the hole map, the emptiest layer under a cell, is the bed's own);
- bond layers 0..n-1, then 0.0 for the absent ones;
- the descriptors ((n - 3) / 3, (nu - 0.28) / 0.1, (psi - 0.08) / 0.04): zero
  for the paper's steel bed of 3 layers.

E enters by scaling (every spring is E times a function of a*, R, nu and psi,
so every modulus is proportional to E and the Poisson ratios do not depend on
it): the network is trained on E = 210 GPa.

:func:`from_small` starts the network from a 3-layer steel model: its weights
for the present layers, zero for the padding channels and the descriptors, so
at the start it gives the small model's output bit for bit on a small bed.
"""
import numpy as np

from amfe.errors import AmfeError

#: The thickest bed, in layers, the input holds; the thinnest the network was trained on.
MAX_LAYERS, MIN_LAYERS = 6, 2
#: The descriptors' reference (the paper's steel, 3 layers) and scale.
REFERENCE = {"layers": 3.0, "nu": 0.28, "psi": 0.08}
SCALE = {"layers": 3.0, "nu": 0.1, "psi": 0.04}
DESCRIPTORS = ("layers", "nu", "psi")
#: The material ranges of the training labels (drawn uniformly; docs/datasets.md).
NU_RANGE, PSI_RANGE = (0.25, 0.40), (0.04, 0.12)
#: E of the training labels [Pa]: a prediction for another E is scaled by E / E_TRAINED.
E_TRAINED = 210e9


def check_bed_kind(layers, nu, psi):
    """AmfeError, quoting the value and the range, for a bed the network was not trained on."""
    if not MIN_LAYERS <= int(layers) <= MAX_LAYERS:
        raise AmfeError(f"the bed has {int(layers)} powder layers; the surrogate reads "
                        f"{MIN_LAYERS} to {MAX_LAYERS} (0.{MIN_LAYERS}-0.{MAX_LAYERS} mm)")
    for name, value, (lo, hi) in (("nu", nu, NU_RANGE), ("psi", psi, PSI_RANGE)):
        if not lo - 1e-12 <= float(value) <= hi + 1e-12:
            raise AmfeError(f"the bed's {name} is {float(value):g}; the surrogate was trained "
                            f"on {name} in [{lo:g}, {hi:g}] (solve it: amfe homogenize)")


def descriptors(layers, nu, psi):
    """(n, 3) float32 descriptors of beds: layers (n,), nu (n,), psi (n,)."""
    values = {"layers": np.asarray(layers, float), "nu": np.asarray(nu, float),
              "psi": np.asarray(psi, float)}
    return np.stack([(values[k] - REFERENCE[k]) / SCALE[k] for k in DESCRIPTORS],
                    axis=-1).astype(np.float32)


def anybed_input(fill, bonds, nu, psi):
    """The network input (2 MAX_LAYERS + 3, H, W) float32 of a bed.

    fill, bonds: (layers, H, W) images of the data set (amfe.dataset.images);
    nu, psi: the bed's material.
    """
    fill, bonds = np.asarray(fill, np.float32), np.asarray(bonds, np.float32)
    n, H, W = fill.shape
    if bonds.shape != fill.shape:
        raise AmfeError(f"fill and bond images differ in shape: {fill.shape} and {bonds.shape}")
    check_bed_kind(n, nu, psi)
    out = np.zeros((2 * MAX_LAYERS + len(DESCRIPTORS), H, W), np.float32)
    out[:n] = fill
    out[n:MAX_LAYERS] = 1.0
    out[MAX_LAYERS:MAX_LAYERS + n] = bonds
    out[2 * MAX_LAYERS:] = descriptors(n, nu, psi)[:, None, None]
    return out


def anybed_inputs(fill, bonds, nu, psi):
    """:func:`anybed_input` of n beds: fill, bonds (n, layers, H, W), nu, psi (n,)."""
    return np.stack([anybed_input(f, b, u, p) for f, b, u, p in zip(fill, bonds, nu, psi)])


def anybed_net(image_hw, width=0.5):
    """A fresh anybed network for (H, W) images (MultiScaleNet, the small model's widths)."""
    from amfe.training.multiscale import MultiScaleNet  # torch: only to build or train one
    H, W = image_hw
    return MultiScaleNet((2 * MAX_LAYERS + len(DESCRIPTORS), H, W), width=width,
                         n_fill=MAX_LAYERS, features=len(DESCRIPTORS))


def from_small(state, image_hw, layers=3, width=0.5):
    """An anybed network whose output on a ``layers``-layer steel bed is that of the
    MultiScaleNet of ``state`` (its state_dict, fill + bond inputs of ``layers`` layers)."""
    import torch
    net = anybed_net(image_hw, width)
    new = net.state_dict()
    old = {k: v.clone() for k, v in state.items()}
    first = "stages.0.0.weight"
    w_old, w_new = old[first], torch.zeros_like(new[first])
    if w_old.shape[1] != 2 * layers + 1:
        raise AmfeError(f"from_small: the model reads {w_old.shape[1] - 1} layers, not "
                        f"{2 * layers} (fill and bonds of {layers})")
    # old: fill 0..L-1, bonds 0..L-1, holes; new: fill 0..5, bonds 0..5, holes
    w_new[:, :layers] = w_old[:, :layers]
    w_new[:, MAX_LAYERS:MAX_LAYERS + layers] = w_old[:, layers:2 * layers]
    w_new[:, 2 * MAX_LAYERS] = w_old[:, 2 * layers]
    old[first] = w_new
    head = "head.0.weight"
    h_old = old[head]
    h_new = torch.zeros_like(new[head])
    h_new[:, :h_old.shape[1]] = h_old
    old[head] = h_new
    net.load_state_dict(old)
    return net

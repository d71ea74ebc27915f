"""Fitting a stiffness network (21 Cholesky outputs) on beds of several sizes.

The data sets store each bed's full stiffness ``C`` (M, 6, 6) [Pa]
(amfe.dataset.datafile) beside the six labels; :func:`read_stiffness`
reads it. :func:`fit_stiffness` trains an :class:`~amfe.training.anysize.AnySizeNet`
(or any net(images, sizes) -> (n, 21)) on groups of equal-size images, one
group per size (a batch holds one size, since the images of a batch must
share H x W), with the loss the mean squared difference of the 21
independent entries of C / scale, and random mirrors / x <-> y swaps that
move C as a tensor (amfe.training.stiffness.augment_stiffness).
"""
import numpy as np
import torch

from amfe.errors import AmfeError
from amfe.training.anysize import AnySizeNet
from amfe.training.stiffness import augment_stiffness, stiffness_from_raw

_UPPER = np.triu_indices(6)


def read_stiffness(path, rows):
    """C (n, 6, 6) float64 [Pa] of data-set ``rows`` (the file's /C)."""
    import h5py  # noqa: PLC0415 (heavy or optional: loaded when used)
    rows = np.asarray(rows, np.int64)
    with h5py.File(path, "r") as f:
        if "C" not in f:
            raise AmfeError(f"{path} has no /C: not a data set with the full stiffness")
        order = np.argsort(rows)
        out = np.empty((rows.size, 6, 6))
        out[order] = f["C"][rows[order]]
    return out


def stiffness_loss(raw, C_norm):
    """Mean squared difference of the 21 independent entries of predicted and given C (normed)."""
    diff = stiffness_from_raw(raw) - C_norm
    return (diff[:, _UPPER[0], _UPPER[1]] ** 2).mean()


def fit_stiffness(net, groups, scale, epochs=50, lr=2e-3, batch_size=16, augment=True, seed=0):
    """Train ``net`` in place on ``groups``: [(images (n, layers, H, W), sizes (n, 2) mm,
    C (n, 6, 6) Pa)], one per image size. Returns the mean loss of each epoch (list).

    scale [Pa]: C's normalised unit (the checkpoint's stiffness_scale), e.g. the
    training beds' median C11.
    """
    if not scale > 0:
        raise AmfeError(f"fit_stiffness: scale must be a positive stiffness in Pa, got {scale}")
    gen = torch.Generator().manual_seed(int(seed))
    torch.manual_seed(int(seed))
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    data = [(torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(s, dtype=torch.float32),
             torch.as_tensor(np.asarray(c) / float(scale), dtype=torch.float32))
            for x, s, c in groups]
    history = []
    for _ in range(int(epochs)):
        net.train()
        batches = [(g, idx) for g, (x, _, _) in enumerate(data)
                   for idx in torch.randperm(x.shape[0], generator=gen).split(int(batch_size))]
        order = torch.randperm(len(batches), generator=gen)
        total = 0.0
        for k in order.tolist():
            g, idx = batches[k]
            x, s, c = (t[idx] for t in data[g])
            if augment:
                x, c = augment_stiffness(x, c, gen, square=x.shape[-1] == x.shape[-2])
            loss = stiffness_loss(net(x, s), c)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        history.append(total / sum(x.shape[0] for x, _, _ in data))
    return history


# An any-size stiffness model is saved as its own format: amfe predict's loader
# (amfe.training.checkpoint, format "amfe.surrogate") refuses it with one line until
# it learns to run one (docs/surrogate.md, "What remains").
STIFFNESS_FORMAT = "amfe.stiffness"


def stiffness_checkpoint(net, arch_args, scale, pixelation, layers, **extra):
    """A plain-data checkpoint dict of an :class:`AnySizeNet` stiffness model.

    arch_args: AnySizeNet's keyword arguments (layers_in, channels, hidden);
    scale [Pa]: C's normalised unit; pixelation: {image_cell, layer_thickness,
    image_spacing}; layers: the image layers the model reads; extra: e.g.
    conformal, tta, metrics.
    """
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    return {"format": STIFFNESS_FORMAT, "format_version": 1, "arch": "anysize",
            "arch_args": {k: (list(v) if isinstance(v, tuple) else v)
                          for k, v in arch_args.items()},
            "members": [state], "stiffness_scale": float(scale), "outputs": "cholesky21",
            "pixelation": dict(pixelation), "layers": int(layers), **extra}


def load_stiffness_model(path):
    """(net in eval mode, checkpoint dict) of a file written from :func:`stiffness_checkpoint`."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is reported the same way
        raise AmfeError(f"cannot read {path} as a stiffness model ({type(exc).__name__})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != STIFFNESS_FORMAT:
        raise AmfeError(f"{path} is not an amfe stiffness model (format {STIFFNESS_FORMAT!r})")
    net = AnySizeNet(**ckpt["arch_args"])
    try:
        net.load_state_dict(ckpt["members"][0])
    except (RuntimeError, KeyError, IndexError) as exc:
        raise AmfeError(f"{path}: the weights do not fit its AnySizeNet ({exc})") from None
    return net.eval(), ckpt

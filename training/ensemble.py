"""The ensemble's arithmetic: test-time augmentation, one network's averaged predictions, and
the members' mean, spread and flag (docs/model.md, section 8). Importing it imports
no torch (only :func:`predict_raw` does), so numpy inference (amfe.training.npnet)
shares it.

The six-constant surrogate (amfe.training.predict) and the full-stiffness one
(amfe.training.stiffness, stiffness_predict) both build on it; it imports
neither, so the inference modules form no import circle.
"""
import numpy as np

from amfe.errors import AmfeError

TTA_MODES = ("none", "flips", "d4")


def tta_mode(value):
    """A checkpoint's test-time augmentation: "none", "flips" (4 mirrors) or "d4" (8 symmetries)."""
    if value is True:
        return "flips"
    if value in (False, None):
        return "none"
    if value not in TTA_MODES:
        raise AmfeError(f"unknown test-time augmentation {value!r}; choose one of "
                        f"{', '.join(TTA_MODES)}")
    return value


def symmetries(mode, square=True):
    """(flip_x, flip_y, transpose) of the label-preserving symmetries a TTA mode averages over."""
    if mode == "none":
        return [(False, False, False)]
    mirrors = [(False, False), (True, False), (False, True), (True, True)]
    out = [(fx, fy, False) for fx, fy in mirrors]
    if mode == "d4" and square:
        out += [(fx, fy, True) for fx, fy in mirrors]
    return out


# Images per forward pass on a CPU: the fastest measured on this project's machine
# (the shipped model, 8 passes over 1 000 beds, one thread: 0.84-0.87 s at 128 images
# a pass, 0.90-0.94 s at 64, 1.02 s at 32, 0.86-0.91 s at 192-256; larger passes'
# activations leave the cache;
# docs/surrogate_scaling.md, "Speed of the eight passes").
CPU_PASS_IMAGES = 128
GPU_PASS_IMAGES = 1024


def predict_raw(net, images, norm, tta="none", batch_size=None):
    """Raw predictions (n, 6) float64 of one network, averaged over the TTA symmetries.

    A mirrored image has the same six labels; an x<->y transposed one has
    them permuted (amfe.training.data.transpose_labels, an involution), so its
    prediction is mapped back before averaging (in raw units). The symmetric
    images of a chunk of beds go through the network in one pass of about
    ``batch_size`` images (default: CPU_PASS_IMAGES on a CPU, GPU_PASS_IMAGES
    on a GPU).
    """
    import torch  # here, not at the top: the numpy inference imports none of torch

    from amfe.training.data import flip_images, transpose_labels
    from amfe.training.device import device_of
    net.eval()
    dev = device_of(net)
    syms = symmetries(tta_mode(tta), images.shape[-1] == images.shape[-2])
    if batch_size is None:
        batch_size = CPU_PASS_IMAGES if dev.type == "cpu" else GPU_PASS_IMAGES
    chunk = max(1, int(batch_size) // len(syms))
    out = []
    with torch.inference_mode():
        for s in range(0, images.shape[0], chunk):
            xb = images[s:s + chunk]
            views = torch.cat([flip_images(xb, fx, fy, tr) for fx, fy, tr in syms])
            y = norm.decode(net(views.to(dev)).cpu()).view(len(syms), xb.shape[0], 6)
            acc = 0.0
            for k, (_, _, tr) in enumerate(syms):
                acc = acc + (transpose_labels(y[k]) if tr else y[k])
            out.append(acc / len(syms))
    return torch.cat(out) if out else torch.zeros(0, 6, dtype=torch.float64)


def relative_spread(members):
    """The members' standard deviation over |mean|, (n, k) of (members, n, k) predictions."""
    members = np.asarray(members, np.float64)
    std = (members - members[:1]).std(axis=0)   # shift-invariant; exactly 0 for equal members
    return std / np.maximum(np.abs(members.mean(axis=0)), np.finfo(float).tiny)


def summarize_members(members, spread_scale=None, threshold=None):
    """Ensemble mean, relative spread, flag score and flag from (members, n, 6) predictions."""
    members = np.asarray(members, np.float64)
    mean = members.mean(axis=0)
    rel = relative_spread(members)
    scale = np.ones(6) if spread_scale is None else np.asarray(spread_scale, np.float64)
    score = np.max(rel / scale, axis=1)
    # NaN > threshold is False: a non-finite prediction is flagged on its own.
    nonfinite = ~np.isfinite(members).all(axis=(0, 2))
    flagged = (score > threshold) if threshold is not None else np.zeros(mean.shape[0], bool)
    return {"mean": mean, "spread": rel, "score": score, "nonfinite": nonfinite,
            "flagged": flagged | nonfinite}

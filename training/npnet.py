"""The multi-scale network's inference in numpy: the shipped models without torch.

:class:`NumpyMultiScale` computes what amfe.training.multiscale.MultiScaleNet
computes (docs/model.md, section 8), from the same state dict (numpy arrays,
amfe.training.torchfile), in float32 like torch on a CPU: 3x3 convolutions
with same padding as matrix products over shifted copies or slices of the
(n, H, W, C) activations (:func:`_conv3x3`), ReLU, 2x2 max pooling (floor),
the hole maps, the per-stage mean and maximum, the head. It agrees with torch to float32
rounding (tests/test_npnet.py: 1e-5 relative on the shipped models). Only
the forward pass lives here; training stays in torch.

:func:`predict_raw` is amfe.training.ensemble.predict_raw for such a network:
the same test-time symmetries, decoding and averaging, in float64.
"""
import numpy as np

from amfe.errors import AmfeError

#: MultiScaleNet's default stage widths and head (amfe.training.multiscale takes them from here).
CHANNELS, HIDDEN = (32, 64, 128, 256), (512, 256, 128)
#: Images per matrix product: about the fastest on one CPU thread (20 x 20 inputs).
PASS_IMAGES = 128


def multiscale_shapes(image_shape, width=1.0, channels=CHANNELS, hidden=HIDDEN, n_fill=None,
                      outputs=6, features=0):
    """{parameter name: shape} of MultiScaleNet(image_shape, ...) (its state dict's keys).

    Mirrors MultiScaleNet.__init__; AmfeError for the sizes it refuses."""
    layers_in, H, W = (int(s) for s in image_shape)
    layers_in -= int(features)
    if min(H, W) < 1 or layers_in < 1:
        raise AmfeError(f"multiscale needs a (layers, H, W) image, got {tuple(image_shape)}")
    n_fill = layers_in if n_fill is None else int(n_fill)
    if not 1 <= n_fill <= layers_in:
        raise AmfeError(f"multiscale: n_fill must lie in [1, {layers_in}], got {n_fill}")
    shapes, c, summary = {}, layers_in, 0
    for k, ch in enumerate(channels):
        out = max(1, int(round(ch * width)))
        shapes.update({f"stages.{k}.0.weight": (out, c + 1, 3, 3), f"stages.{k}.0.bias": (out,),
                       f"stages.{k}.2.weight": (out, out, 3, 3), f"stages.{k}.2.bias": (out,)})
        summary += 2 * out
        c = out
    w = summary + int(features)
    for k, h in enumerate(list(hidden) + [outputs]):
        shapes[f"head.{2 * k}.weight"] = (int(h), w)
        shapes[f"head.{2 * k}.bias"] = (int(h),)
        w = int(h)
    return shapes


def _conv3x3(x, w, b):
    """ReLU(3x3 convolution, same padding) of x (n, H, W, C): (n, H, W, out); w (9 C, out).

    Maps larger than 10 x 10: nine products of the zero-padded activations, flattened over
    (n, H + 2, W + 2), each shifted by one tap's offset, which is a contiguous slice, so
    nothing is copied nine times (the outputs on the padding are computed and dropped);
    smaller maps: one product of the nine shifted copies side by side (im2col), which
    keeps the product wide. The faster of the two at each size: the shipped small model's
    128 images took 42 ms against 50-61 ms with im2col alone (one process, 2026-12-06).
    """
    n, H, W, C = x.shape
    if H * W <= 100:
        xp = np.zeros((n, H + 2, W + 2, C), np.float32)
        xp[:, 1:-1, 1:-1] = x
        cols = np.concatenate([xp[:, dy:dy + H, dx:dx + W] for dy in range(3)
                               for dx in range(3)], axis=3)
        y = cols.reshape(n * H * W, 9 * C) @ w
        y += b
        np.maximum(y, 0, out=y)
        return y.reshape(n, H, W, -1)
    rows = n * (H + 2) * (W + 2)
    xp = np.zeros((rows + 2 * (W + 2) + 2, C), np.float32)   # the last taps read past the end
    xp[:rows].reshape(n, H + 2, W + 2, C)[:, 1:-1, 1:-1] = x
    taps = w.reshape(9, C, -1)
    y = xp[:rows] @ taps[0]
    for k in range(1, 9):
        off = (k // 3) * (W + 2) + k % 3
        y += xp[off:off + rows] @ taps[k]
    y = y.reshape(n, H + 2, W + 2, -1)[:, :H, :W] + b
    np.maximum(y, 0, out=y)
    return y


def _pool(x):
    """2x2 max pooling, stride 2, floor mode, of (n, H, W, C)."""
    h, w = x.shape[1] // 2, x.shape[2] // 2
    x = x[:, :2 * h, :2 * w]
    x = np.maximum(x[:, 0::2], x[:, 1::2])
    return np.maximum(x[:, :, 0::2], x[:, :, 1::2])


class NumpyMultiScale:
    """MultiScaleNet's forward pass from its state dict ``state`` (name: array)."""

    def __init__(self, state, image_shape, arch_args=None):
        args = dict(arch_args or {})
        self.features = int(args.get("features", 0))
        layers_in = int(image_shape[0]) - self.features
        self.n_fill = layers_in if args.get("n_fill") is None else int(args["n_fill"])
        channels = args.get("channels", CHANNELS)
        hw = (int(image_shape[1]), int(image_shape[2]))
        self.convs, self.pool_after = [], []
        for k in range(len(channels)):
            pair = []
            for j in (0, 2):
                w = np.asarray(state[f"stages.{k}.{j}.weight"], np.float32)
                # (out, in, 3, 3) -> (3, 3, in, out) -> (9 in, out): the im2col order
                pair.append((np.ascontiguousarray(w.transpose(2, 3, 1, 0).reshape(-1, w.shape[0])),
                             np.asarray(state[f"stages.{k}.{j}.bias"], np.float32)))
            self.convs.append(pair)
            pool = k < len(channels) - 1 and min(hw) >= 2
            self.pool_after.append(pool)
            if pool:
                hw = (hw[0] // 2, hw[1] // 2)
        n_head = len(args.get("hidden", HIDDEN)) + 1
        self.head = [(np.ascontiguousarray(np.asarray(state[f"head.{2 * k}.weight"],
                                                      np.float32).T),
                      np.asarray(state[f"head.{2 * k}.bias"], np.float32))
                     for k in range(n_head)]

    def __call__(self, x):
        """Outputs (n, outputs) float32 of images x (n, layers, H, W)."""
        x = np.asarray(x, np.float32)
        z = x[:, x.shape[1] - self.features:].mean(axis=(2, 3)) if self.features else None
        if self.features:
            x = x[:, :-self.features]
        x = np.ascontiguousarray(x.transpose(0, 2, 3, 1))          # NHWC
        holes = 1.0 - x[..., :self.n_fill].min(axis=3, keepdims=True)
        summaries = []
        for (c1, c2), pool in zip(self.convs, self.pool_after):
            x = _conv3x3(_conv3x3(np.concatenate([x, holes], axis=3), *c1), *c2)
            mean, top = x.mean(axis=(1, 2)), x
            if pool:
                x, holes = _pool(x), _pool(holes)
                if top.shape[1] % 2 == 0 and top.shape[2] % 2 == 0:
                    top = x     # the same maximum, from the pooled map
            summaries += [mean, top.max(axis=(1, 2))]
        h = np.concatenate(summaries + ([z] if z is not None else []), axis=1)
        for k, (w, b) in enumerate(self.head):
            h = h @ w + b
            if k < len(self.head) - 1:
                np.maximum(h, 0, out=h)
        return h


def _flip(x, fx, fy, tr):
    """amfe.training.data.flip_images on an array (n, layers, H, W)."""
    if fx:
        x = x[..., ::-1]
    if fy:
        x = x[..., ::-1, :]
    return x.swapaxes(-1, -2) if tr else x


def _transpose_labels(y):
    """amfe.training.data.transpose_labels on an array (n, 6)."""
    return np.stack([y[:, 1], y[:, 0], y[:, 2], y[:, 4], y[:, 3], y[:, 5] * y[:, 1] / y[:, 0]],
                    axis=1)


def decode(z, normalizer):
    """Normalised outputs (n, 6) -> raw labels (n, 6) float64 (Normalizer.decode)."""
    y = np.asarray(z, np.float64) * np.asarray(normalizer["std"], np.float64) \
        + np.asarray(normalizer["mean"], np.float64)
    log = np.asarray(normalizer["log"], bool)
    with np.errstate(over="ignore"):   # an overflow is inf, flagged non-finite (as in torch)
        return np.where(log, np.exp(np.where(log, y, 0.0)), y)


def predict_raw(net, images, normalizer, syms, batch_size=None):
    """Raw predictions (n, 6) float64 of ``net`` on images (n, layers, H, W), averaged over
    ``syms`` ((flip_x, flip_y, transpose) each, amfe.training.ensemble.symmetries), the
    transposed views' labels mapped back; ``normalizer``: the checkpoint's dict."""
    images = np.asarray(images, np.float32)
    chunk = max(1, int(batch_size or PASS_IMAGES) // len(syms))
    out = []
    for s in range(0, images.shape[0], chunk):
        xb = images[s:s + chunk]
        views = np.concatenate([_flip(xb, *sym) for sym in syms])
        y = decode(net(views), normalizer).reshape(len(syms), xb.shape[0], 6)
        acc = sum(_transpose_labels(y[k]) if sym[2] else y[k] for k, sym in enumerate(syms))
        out.append(acc / len(syms))
    return np.concatenate(out) if out else np.zeros((0, 6))

"""The four CNNs of the paper's comparison (section 7), adapted to the image shape.

Every network maps a (batch, layers, H, W) image to (batch, 6) outputs through
the same kind of regression head: a stack of fully connected layers with ReLU
and a last *linear* layer with six outputs (the paper's "multiple output
linear regression layer" in place of the softmax classifier). The outputs are
the normalised labels (:class:`amfe.training.data.Normalizer`).

- ``custom``: Custom Net, docs/model.md, section 8 / paper figure 6. Four blocks of
  3x3 convolution (16, 32, 64, 128 channels) + ReLU + 2x2 max pooling, then
  FC 512 -> 256 -> 128 (ReLU) -> 6 (linear). Padding ``"valid"`` (Keras's
  default, the paper's) when the image survives the four blocks that way,
  else ``"same"``: on the paper's 1 x 100 x 100 input valid padding gives
  100 -> 49 -> 23 -> 10 -> 4, 128 x 4 x 4 features and 1 311 238 parameters,
  the paper's "1.31 million"; on its 3 x 100 x 100 images 1 311 526. A
  ``small`` image (3 x 20 x 20) does not survive valid padding (20 -> 9 -> 3 ->
  0), so it gets same padding: 20 -> 10 -> 5 -> 2 -> 1, 128 features and
  328 486 parameters (1.3 MB in float32). On images under 16 x 16 (the
  test suite's ``tiny`` scale, 1 x 5 x 5) the poolings that would shrink the
  map below 1 x 1 are skipped.
- ``lenet5``: LeNet-5 with ReLU and max pooling: 5x5 convolution to 6
  channels (padding 2, as LeNet on 28 x 28 digits), pool, 5x5 to 16, pool,
  at most 5 x 5 positions kept by adaptive average pooling (LeNet's 16 x 5 x 5
  for large inputs), FC 120 -> 84 -> 6. 61 666 parameters on 3 x 100 x 100
  (the paper: 59 thousand), 30 946 on 3 x 20 x 20.
- ``alexnet``: AlexNet's five convolutions (64, 192, 384, 256, 256 channels,
  pools after the first, second and fifth) with 3x3 kernels and stride 1,
  since a 20 x 20 image has no room for the 11x11 stride-4 stem; adaptive
  average pooling to at most 6 x 6 (AlexNet's); FC ``hidden`` (default 4096,
  4096) with dropout 0.5 -> 6.
- ``vgg``: VGG-11 (configuration A: 64, M, 128, M, 256, 256, M, 512, 512, M,
  512, 512, M) with 3x3 convolutions; a pooling that would shrink the map
  below 1 x 1 is skipped (a 20 x 20 image takes four); optional batch
  normalisation; adaptive average pooling to at most 7 x 7; FC ``hidden``
  (default 4096, 4096) with dropout 0.5 -> 6. ``width`` scales every channel
  count (AlexNet and VGG), ``hidden`` the FC widths, so the comparison can be
  run at a size this CPU trains in minutes; the arguments travel in the
  checkpoint.

:func:`build_net` (name, image shape, arguments) is how checkpoints rebuild
a network; :func:`count_parameters` counts trainable parameters.
"""
import torch
from torch import nn

from amfe.errors import AmfeError
from amfe.training import ARCH_NAMES, check_arch_args
from amfe.training.multiscale import MultiScaleNet

N_OUTPUTS = 6


def regression_head(in_features, hidden, dropout=0.0):
    """FC layers ``hidden`` with ReLU (and dropout), then a linear layer with 6 outputs."""
    layers, width = [], int(in_features)
    for h in hidden:
        layers += [nn.Linear(width, int(h)), nn.ReLU(inplace=True)]
        if dropout:
            layers.append(nn.Dropout(dropout))
        width = int(h)
    layers.append(nn.Linear(width, N_OUTPUTS))
    return nn.Sequential(*layers)


class MaxPool2x2(nn.Module):
    """2x2 max pooling, stride 2, floor mode: the same numbers as nn.MaxPool2d(2).

    Written as two strided maxima because torch's CPU max_pool2d (which also
    computes argmax indices) is slow on these small maps (docs/benchmarks.md,
    "Figures quoted in the code"). No parameters, so checkpoints are unaffected.
    """

    def forward(self, x):
        h, w = x.shape[-2] // 2, x.shape[-1] // 2
        x = x[..., :2 * h, :2 * w]
        x = torch.maximum(x[..., 0::2, :], x[..., 1::2, :])
        return torch.maximum(x[..., 0::2], x[..., 1::2])


def _check_shape(image_shape):
    try:
        shape = tuple(int(s) for s in image_shape)
    except (TypeError, ValueError):
        raise AmfeError(f"image shape must be (layers, H, W), got {image_shape!r}") from None
    if len(shape) != 3 or min(shape) < 1:
        raise AmfeError(f"image shape must be three positive sizes (layers, H, W), got {shape}")
    return shape


def _out_hw(hw, kernel, pad, pool):
    """Spatial size after a conv (stride 1) and an optional 2x2 pooling."""
    h, w = (s + 2 * pad - kernel + 1 for s in hw)
    return (h // 2, w // 2) if pool else (h, w)


def custom_padding(image_shape):
    """"valid" if the image survives Custom Net's four valid conv + pool blocks, else "same"."""
    hw = _check_shape(image_shape)[1:]
    for _ in range(4):
        hw = _out_hw(hw, 3, 0, True)
    return "valid" if min(hw) >= 1 else "same"


class CustomNet(nn.Module):
    """Custom Net (paper figure 6, docs/model.md, section 8); see the module docstring."""

    CHANNELS = (16, 32, 64, 128)
    HIDDEN = (512, 256, 128)

    def __init__(self, image_shape, padding="auto", width=1.0, convs=1):
        super().__init__()
        layers_in, H, W = _check_shape(image_shape)
        if int(convs) < 1:
            raise AmfeError(f"Custom Net needs at least one convolution per block, got {convs}")
        if padding == "auto":
            padding = custom_padding(image_shape)
        if padding not in ("valid", "same"):
            raise AmfeError(f"Custom Net padding must be auto, valid or same, got {padding!r}")
        pad = 0 if padding == "valid" else 1
        layers, c, hw = [], layers_in, (H, W)
        for out in self.CHANNELS:
            out = _ch(out, width)
            for _ in range(int(convs)):   # convs > 1: a deeper block (same padding keeps hw)
                layers += [nn.Conv2d(c, out, 3, padding=pad), nn.ReLU(inplace=True)]
                c, hw = out, _out_hw(hw, 3, pad, False)
            if min(hw) < 1:
                raise AmfeError(f"Custom Net with {padding} padding needs a larger image than "
                                f"{H} x {W}")
            if min(hw) >= 2:     # a pooling below 1 x 1 is skipped (images under 16 x 16)
                layers.append(MaxPool2x2())
                hw = (hw[0] // 2, hw[1] // 2)
        self.padding = padding
        self.features = nn.Sequential(*layers)
        self.head = regression_head(c * hw[0] * hw[1], self.HIDDEN)

    def forward(self, x):
        return self.head(torch.flatten(self.features(x), 1))


class LeNet5(nn.Module):
    """LeNet-5 with ReLU and max pooling; see the module docstring."""

    def __init__(self, image_shape):
        super().__init__()
        layers_in, H, W = _check_shape(image_shape)
        hw = _out_hw((H, W), 5, 2, True)
        hw = _out_hw(hw, 5, 0, True)
        if min(hw) < 1:
            raise AmfeError(f"LeNet-5 needs images of at least 12 x 12, got {H} x {W}")
        keep = (min(hw[0], 5), min(hw[1], 5))
        self.features = nn.Sequential(
            nn.Conv2d(layers_in, 6, 5, padding=2), nn.ReLU(inplace=True), MaxPool2x2(),
            nn.Conv2d(6, 16, 5), nn.ReLU(inplace=True), MaxPool2x2(),
            nn.AdaptiveAvgPool2d(keep))
        self.head = regression_head(16 * keep[0] * keep[1], (120, 84))

    def forward(self, x):
        return self.head(torch.flatten(self.features(x), 1))


def _ch(c, width):
    return max(1, int(round(c * width)))


class AlexNet(nn.Module):
    """AlexNet adapted to small images (3x3 stride-1 convolutions); see the module docstring."""

    CHANNELS = (64, 192, 384, 256, 256)
    POOL_AFTER = (0, 1, 4)

    def __init__(self, image_shape, width=1.0, hidden=(4096, 4096), dropout=0.5):
        super().__init__()
        layers_in, H, W = _check_shape(image_shape)
        layers, c, hw = [], layers_in, (H, W)
        for k, out in enumerate(self.CHANNELS):
            out = _ch(out, width)
            layers += [nn.Conv2d(c, out, 3, padding=1), nn.ReLU(inplace=True)]
            c = out
            if k in self.POOL_AFTER and min(hw) >= 2:
                layers.append(MaxPool2x2())
                hw = (hw[0] // 2, hw[1] // 2)
        _pooled_head(self, layers, c, hw, 6, hidden, dropout)

    def forward(self, x):
        return self.head(torch.flatten(self.features(x), 1))


def _pooled_head(net, layers, c, hw, keep_max, hidden, dropout):
    """Close a feature stack with an adaptive pool to at most keep_max^2 and the head."""
    keep = (min(hw[0], keep_max), min(hw[1], keep_max))
    layers.append(nn.AdaptiveAvgPool2d(keep))
    net.features = nn.Sequential(*layers)
    net.head = regression_head(c * keep[0] * keep[1], hidden, dropout)


class VGG(nn.Module):
    """VGG-11 (configuration A), pools skipped below 1 x 1; see the module docstring."""

    CONFIG = (64, "M", 128, "M", 256, 256, "M", 512, 512, "M", 512, 512, "M")

    def __init__(self, image_shape, width=1.0, hidden=(4096, 4096), dropout=0.5,
                 batch_norm=False):
        super().__init__()
        layers_in, H, W = _check_shape(image_shape)
        layers, c, hw = [], layers_in, (H, W)
        for v in self.CONFIG:
            if v == "M":
                if min(hw) >= 2:
                    layers.append(MaxPool2x2())
                    hw = (hw[0] // 2, hw[1] // 2)
                continue
            out = _ch(v, width)
            layers.append(nn.Conv2d(c, out, 3, padding=1))
            if batch_norm:
                layers.append(nn.BatchNorm2d(out))
            layers.append(nn.ReLU(inplace=True))
            c = out
        _pooled_head(self, layers, c, hw, 7, hidden, dropout)

    def forward(self, x):
        return self.head(torch.flatten(self.features(x), 1))


ARCHITECTURES = dict(zip(ARCH_NAMES, (CustomNet, LeNet5, AlexNet, VGG, MultiScaleNet)))
DISPLAY_NAMES = {"custom": "Custom Net", "lenet5": "LeNet-5", "alexnet": "AlexNet", "vgg": "VGG",
                 "multiscale": "Multi-scale"}
def build_net(arch, image_shape, arch_args=None):
    """A fresh network ``arch`` (custom, lenet5, alexnet, vgg) for images of ``image_shape``."""
    if arch not in ARCHITECTURES:
        raise AmfeError(f"unknown architecture {arch!r}; choose one of {', '.join(ARCHITECTURES)}")
    arch_args = check_arch_args(arch, arch_args)
    return ARCHITECTURES[arch](_check_shape(image_shape), **arch_args)


def resolved_args(arch, net, arch_args=None):
    """The arguments that rebuild ``net`` exactly (Custom Net's "auto" padding resolved)."""
    out = dict(arch_args or {})
    if arch == "custom":
        out["padding"] = net.padding
    if "hidden" in out:
        out["hidden"] = [int(h) for h in out["hidden"]]
    return out


def count_parameters(net):
    """Trainable parameters of ``net``."""
    return int(sum(p.numel() for p in net.parameters() if p.requires_grad))

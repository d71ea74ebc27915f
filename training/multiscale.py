"""A multi-scale network that reads the holes of a bed: ``multiscale``.

The surrogate's error sits in beds with skipped scan pieces (docs/surrogate.md):
the constants depend on where the holes are and how they connect, which a
chain of poolings and one flattened 1 x 1 map (Custom Net on a 20 x 20 image)
blurs. This encoder keeps every scale:

- an encoder of ``len(channels)`` stages (two 3x3 convolutions with same
  padding and ReLU each; 2x2 max pooling between stages, skipped below 2 x 2);
- the input's *hole map* at each stage's resolution, 1 - min-pooled fill
  (the emptiest cell under each position), joins that stage as an extra
  channel, so a hole of one cell is not averaged away by the poolings;
- every stage is summarised by its global average and global maximum, and
  the head (FC ``hidden`` with ReLU, then 6 linear outputs) reads all of them,
  fine and coarse: the U-Net's skip connections, ending in a regression.

The input is the data set's image stack (fill layers first, then bond
layers when the model reads them; ``n_fill`` says how many are fill), so
``amfe predict`` computes it from a bed file alone.
"""
import torch
from torch import nn
from torch.nn import functional as F

from amfe.errors import AmfeError
from amfe.training.npnet import CHANNELS, HIDDEN


class MultiScaleNet(nn.Module):
    """Multi-scale encoder with hole maps and per-scale summaries; see the module docstring.

    image_shape: (layers, H, W); channels: per-stage widths (times ``width``);
    n_fill: how many leading layers are volume fractions (default: all); outputs: the
    last layer's width (6 constants; 21 for a stiffness head, amfe.training.stiffness);
    features: how many numbers per bed the head reads beside the image's summaries: the
    last ``features`` layers of the input are constant planes holding them (so flips,
    batching and every image path carry them unchanged; amfe.training.anybed's bed
    descriptors), read as their means; image_shape counts them.
    """

    def __init__(self, image_shape, width=1.0, channels=CHANNELS, hidden=HIDDEN, n_fill=None,
                 outputs=6, features=0):
        super().__init__()
        layers_in, H, W = (int(s) for s in image_shape)
        layers_in -= int(features)   # the descriptor planes go to the head, not the encoder
        if min(H, W) < 1 or layers_in < 1:
            raise AmfeError(f"multiscale needs a (layers, H, W) image, got {tuple(image_shape)}")
        self.n_fill = layers_in if n_fill is None else int(n_fill)
        if not 1 <= self.n_fill <= layers_in:
            raise AmfeError(f"multiscale: n_fill must lie in [1, {layers_in}], got {n_fill}")
        self.stages = nn.ModuleList()
        self.pool_after = []
        c, hw = layers_in, (H, W)
        summary = 0
        for k, ch in enumerate(channels):
            out = max(1, int(round(ch * width)))
            self.stages.append(nn.Sequential(
                nn.Conv2d(c + 1, out, 3, padding=1), nn.ReLU(inplace=True),
                nn.Conv2d(out, out, 3, padding=1), nn.ReLU(inplace=True)))
            summary += 2 * out
            pool = k < len(channels) - 1 and min(hw) >= 2
            self.pool_after.append(pool)
            if pool:
                hw = (hw[0] // 2, hw[1] // 2)
            c = out
        self.features = int(features)
        layers, w = [], summary + self.features
        for h in hidden:
            layers += [nn.Linear(w, int(h)), nn.ReLU(inplace=True)]
            w = int(h)
        layers.append(nn.Linear(w, int(outputs)))
        self.head = nn.Sequential(*layers)

    def forward(self, x):
        if not self.features:
            return self.head(self.encode(x))
        z = x[:, -self.features:].mean(dim=(2, 3))
        return self.head(torch.cat([self.encode(x[:, :-self.features]), z], dim=1))

    def encode(self, x):
        """The per-stage summaries (n, sum of 2 x stage widths) of images x (n, layers, H, W)."""
        # The emptiest fill layer under each cell; 1 - it is the hole map.
        holes = 1.0 - x[:, :self.n_fill].amin(dim=1, keepdim=True)
        summaries = []
        for stage, pool in zip(self.stages, self.pool_after):
            x = stage(torch.cat([x, holes], dim=1))
            mean, top = x.mean(dim=(2, 3)), x
            if pool:
                x = F.max_pool2d(x, 2)
                holes = F.max_pool2d(holes, 2)   # a hole anywhere in the 2 x 2 block stays
                if top.shape[-1] % 2 == 0 and top.shape[-2] % 2 == 0:
                    # The same maximum from the 2 x 2 maxima that cover the map: torch's
                    # amax over a 64 x 16 x 20 x 20 block took 1.2 ms, over its pooled
                    # 10 x 10 maps 12 us (one thread; docs/surrogate_scaling.md,
                    # "Speed of the eight passes").
                    top = x
            summaries += [mean, top.amax(dim=(2, 3))]
        return torch.cat(summaries, dim=1)

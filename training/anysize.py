"""A fully convolutional network for beds of any size, and the whole-cell imaging rule.

:class:`AnySizeNet` (``anysize``): stages of two 3x3 convolutions (same
padding, ReLU) with 2x2 max pooling between them (skipped below 2 x 2), a
global average and a global maximum over the last map, so the head sees a
fixed-length vector whatever the image's H x W; the bed's in-plane size
(Lx, Ly in mm) is concatenated to the pooled features, because the label
depends on size as well as on the image (KUBC's boundary stiffening,
docs/report.md section 3). The head (FC ``hidden``, ReLU) ends in 21 raw
outputs, a Cholesky factor of C (amfe.training.stiffness), or in 6 for the
six constants. One network reads 0.6 mm (20 x 20), 1.2 mm (40 x 40) and
3 mm (100 x 100) beds.

The whole-cell rule (docs/surrogate.md, "Any size") lives in amfe.training.imagebox
(no torch).
"""
import numpy as np
import torch
from torch import nn

from amfe.errors import AmfeError
from amfe.training.imagebox import bed_size, image_any_size
from amfe.training.stiffness import constants_from_stiffness, predict_stiffness


def size_features(sizes):
    """The size input (n, 2) float32 of beds' sizes (n, >= 2) [m]: Lx and Ly in mm."""
    return torch.as_tensor(sizes, dtype=torch.float32)[:, :2] * 1e3


def predict_any_size(net, beds, pixelation, layers, scale=1.0, tta="none"):
    """C (n, 6, 6) [Pa] and the nine constants (n, 9) of beds of any size (whole-cell rule).

    pixelation: {image_cell, layer_thickness, image_spacing} as in checkpoints;
    each bed is imaged by :func:`image_any_size` and predicted with its cropped
    size (amfe.training.stiffness.predict_stiffness, tensor TTA).
    """

    cell, t = pixelation["image_cell"], float(pixelation["layer_thickness"])
    dtype = next(net.parameters()).dtype
    out = []
    for bed in beds:
        image, box = image_any_size(bed, bed_size(bed, layers, t), cell, t,
                                    pixelation["image_spacing"])
        out.append(predict_stiffness(net, torch.as_tensor(image, dtype=dtype)[None],
                                     size_features([box]).to(dtype), tta, scale)[0])
    C = np.stack(out)
    return C, constants_from_stiffness(C)


class AnySizeNet(nn.Module):
    """Fully convolutional encoder, global pooling, the bed's size, a regression head.

    layers_in: image layers; channels: per-stage widths; outputs: 21 (a
    Cholesky factor of C) or 6. forward(images (n, layers, H, W), sizes
    (n, 2) [mm]) -> (n, outputs).
    """

    def __init__(self, layers_in, channels=(16, 32, 64), hidden=(128, 64), outputs=21):
        super().__init__()
        if int(layers_in) < 1 or int(outputs) not in (6, 21):
            raise AmfeError(f"anysize needs >= 1 layer and 6 or 21 outputs, got {layers_in}, "
                            f"{outputs}")
        self.stages = nn.ModuleList()
        c = int(layers_in)
        for ch in channels:
            self.stages.append(nn.Sequential(
                nn.Conv2d(c, int(ch), 3, padding=1), nn.ReLU(inplace=True),
                nn.Conv2d(int(ch), int(ch), 3, padding=1), nn.ReLU(inplace=True)))
            c = int(ch)
        layers, w = [], 2 * c + 2
        for h in hidden:
            layers += [nn.Linear(w, int(h)), nn.ReLU(inplace=True)]
            w = int(h)
        layers.append(nn.Linear(w, int(outputs)))
        self.head = nn.Sequential(*layers)

    def pooled(self, x):
        """The size-free features (n, 2 * channels[-1]): global mean and max of the last map."""
        for k, stage in enumerate(self.stages):
            x = stage(x)
            if k < len(self.stages) - 1 and min(x.shape[-2:]) >= 2:
                x = nn.functional.max_pool2d(x, 2)
        return torch.cat([x.mean(dim=(2, 3)), x.amax(dim=(2, 3))], dim=1)

    def forward(self, x, sizes):
        sizes = torch.as_tensor(sizes, dtype=x.dtype, device=x.device).reshape(x.shape[0], 2)
        return self.head(torch.cat([self.pooled(x), sizes], dim=1))

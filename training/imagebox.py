"""The whole-cell imaging rule: the box a bed of any size is imaged in (no torch).

The whole-cell rule (docs/surrogate.md, "Any size"): a bed's image covers
floor(L / cell) whole cells along x and y from the box's origin (a length
within 1e-6 of a cell of a whole number counts as whole); the strip left
over, under one cell wide, is cropped, never imaged as a partial cell that
would read as void. The size the network reads is the cropped one. The
height must hold the model's layers to within HEIGHT_TOL of a layer (else
AmfeError). A bed file without a recorded size gets the box from the origin
(the generator's corner) to its spheres' far faces, max(centre + radius),
then the same cropping.
"""
import math

import numpy as np

from amfe.dataset.images import pixelate
from amfe.errors import AmfeError

# A length this close (in cells) to a whole number of cells is that whole number:
# 0.6e-3 / 30e-6 is 19.999999999999996 in floating point.
WHOLE_CELL_TOL = 1e-6


# A bed's height may differ from the model's layers x layer thickness by this many layers.
HEIGHT_TOL = 0.05


def bed_size(bed, layers, layer_thickness):
    """The size (x, y, z) [m] a bed is imaged at: its recorded size, else the origin to its
    spheres' far faces; AmfeError if its height is not ``layers`` layers (within HEIGHT_TOL)."""
    size = bed.attrs.get("size") if hasattr(bed, "attrs") else None
    if size is None:
        size = np.max(np.asarray(bed.centers) + np.asarray(bed.radii)[:, None], axis=0)
    size = tuple(float(s) for s in size)
    if abs(size[2] / float(layer_thickness) - int(layers)) > HEIGHT_TOL:
        raise AmfeError(f"the bed is {size[2] * 1e3:g} mm high; the model reads {int(layers)} "
                        f"layers of {float(layer_thickness) * 1e3:g} mm")
    return size


def whole_cells(length, cell):
    """The number of whole cells of ``cell`` [m] in ``length`` [m] (>= 1, else AmfeError)."""
    n = math.floor(float(length) / float(cell) + WHOLE_CELL_TOL)
    if n < 1:
        raise AmfeError(f"a bed {float(length) * 1e3:g} mm wide holds no whole "
                        f"{float(cell) * 1e3:g} mm cell: too small to image")
    return n


def cropped_box(size, cell):
    """The imaged box's size (x, y, z) [m]: x and y cropped to whole cells, z as given."""
    return (whole_cells(size[0], cell[0]) * float(cell[0]),
            whole_cells(size[1], cell[1]) * float(cell[1]), float(size[2]))


def image_any_size(bed, size, cell, layer_thickness, spacing):
    """(image (layers, H, W) float32, cropped size (x, y, z) [m]) of ``bed``, by whole cells."""

    box = cropped_box(size, cell)
    image = pixelate(bed, cell=tuple(cell[:2]), layer_thickness=float(layer_thickness),
                     box=((0.0, 0.0, 0.0), box), spacing=float(spacing))
    return np.asarray(image, np.float32), box

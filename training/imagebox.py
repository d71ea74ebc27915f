"""The whole-cell imaging rule: the box a bed of any size is imaged in, and the sample
spacing a prediction images it at (no torch).

The whole-cell rule (docs/surrogate.md, "Any size"): a bed's image covers
floor(L / cell) whole cells along x and y from the box's origin (a length
within 1e-6 of a cell of a whole number counts as whole); the strip left
over, under one cell wide, is cropped, never imaged as a partial cell that
would read as void. The size the network reads is the cropped one. The
height must hold the model's layers to within HEIGHT_TOL of a layer (else
AmfeError). A bed file without a recorded size gets the box from the origin
(the generator's corner) to its spheres' far faces, max(centre + radius),
then the same cropping. A bed of over :data:`MAX_SAMPLE_LINES` sample lines is sampled at
twice the training's spacing (:func:`sample_spacing`; docs/surrogate.md, "Large beds").
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

#: A bed whose image would take more in-plane sample lines than this at the training's
#: spacing is sampled at twice that spacing (docs/surrogate.md, "Large beds: the imaging's
#: sampling"): a 3 mm bed has 1.44 M lines at 2.5 um (the exact union took 0.16 s of one
#: core) and 0.36 M at 5 um (0.05 s). On 150 held-out 3 mm beds that moved the predicted
#: constants by 0.014-0.039 % on average (at most 0.29 %), against the model's own
#: 1.6-2.9 % mean error, which moved by at most 0.007 points.
MAX_SAMPLE_LINES = 1_000_000
#: The training grid that rule was measured on, (cell side, spacing) [m]: the shipped
#: models' 0.03 mm cells at 2.5 um. A model trained on another grid is imaged at its own
#: spacing at every size (the fill check's shift, amfe.training.fillcheck, is this grid's).
MEASURED_GRID = (30e-6, 2.5e-6)


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


def sample_spacing(box, cell, spacing):
    """The in-plane sample spacing [m] a prediction images ``box`` (x, y[, z]) [m] with:
    the training's ``spacing`` [m], or twice it where that would take more than
    :data:`MAX_SAMPLE_LINES` sample lines (cells (x, y) [m], ceil(cell / spacing) lines a
    cell side, as amfe.dataset.images.pixelate samples), on :data:`MEASURED_GRID` only."""
    side, h = MEASURED_GRID
    if not (math.isclose(float(cell[0]), side) and math.isclose(float(cell[1]), side)
            and math.isclose(float(spacing), h)):
        return float(spacing)
    lines = 1
    for a in (0, 1):
        cells = max(1, math.ceil(float(box[a]) / float(cell[a]) - WHOLE_CELL_TOL))
        lines *= cells * max(1, math.ceil(float(cell[a]) / float(spacing) - WHOLE_CELL_TOL))
    return 2.0 * float(spacing) if lines > MAX_SAMPLE_LINES else float(spacing)


def sampling_note(box, cell, spacing):
    """The record's note on a coarser sampling (:func:`sample_spacing`), or None."""
    used = sample_spacing(box, cell, spacing)
    if used == float(spacing):
        return None
    return (f"imaged at {used * 1e6:g} um in-plane sampling, twice the training's "
            f"{float(spacing) * 1e6:g} um: a bed of over {MAX_SAMPLE_LINES:,} sample lines "
            "(docs/surrogate.md, \"Large beds\")")


def image_any_size(bed, size, cell, layer_thickness, spacing):
    """(image (layers, H, W) float32, cropped size (x, y, z) [m]) of ``bed``, by whole cells,
    sampled at :func:`sample_spacing` of the training's ``spacing`` [m]."""

    box = cropped_box(size, cell)
    image = pixelate(bed, cell=tuple(cell[:2]), layer_thickness=float(layer_thickness),
                     box=((0.0, 0.0, 0.0), box), spacing=sample_spacing(box, cell, spacing))
    return np.asarray(image, np.float32), box

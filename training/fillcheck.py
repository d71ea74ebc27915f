"""The fill check: a bed whose fullest cells are fuller or emptier than every training bed's
is flagged ("another enlargement?"; docs/surrogate.md). Its statistic is the 99th
percentile of a bed's pixels; a checkpoint's ``fill_range`` is that statistic's range
over its training beds (:func:`calibrate_fill`), and a bed imaged at a coarser sampling
than the training's has its statistic's measured shift taken off (:func:`fill_shift`)."""
import numpy as np

from amfe.training.imagebox import sample_spacing

FILL_PERCENTILE = 99.0


def fill_statistic(images):
    """The fill of each bed's fullest cells: the 99th percentile of its pixels, (n,) float64.

    images (n, layers, H, W) volume fractions [-] (or one image (layers, H, W)).
    """
    x = np.asarray(images, np.float64)
    if x.ndim == 3:
        x = x[None]
    return np.percentile(x.reshape(x.shape[0], -1), FILL_PERCENTILE, axis=1)


def calibrate_fill(images, lo=0.5, hi=99.5):
    """The accepted range of :func:`fill_statistic`: its lo-th and hi-th percentiles, ``images``."""
    f = fill_statistic(images)
    return {"lo": float(np.percentile(f, lo)), "hi": float(np.percentile(f, hi)),
            "percentiles": [float(lo), float(hi)],
            "definition": f"{FILL_PERCENTILE:g}th percentile of a bed's pixels (fill of its "
                          "fullest cells, which measures the enlargement); a bed outside "
                          "[lo, hi], the given percentiles over the training beds, is flagged"}


#: How much higher the fill check's statistic (the 99th percentile of a bed's pixels,
#: :func:`fill_statistic`) reads at twice the spacing: the sampling's noise
#: widens the pixels' spread. Measured on the 200 calibration beds of the paper scale
#: (seed 23): +0.0046, sd 0.0013 (docs/surrogate.md, "Large beds").
COARSE_FILL_SHIFT = 0.0046


def fill_shift(box, cell, spacing):
    """:data:`COARSE_FILL_SHIFT` where :func:`sample_spacing` samples ``box`` coarser than
    ``spacing``, else 0.0."""
    return COARSE_FILL_SHIFT if sample_spacing(box, cell, spacing) != float(spacing) else 0.0

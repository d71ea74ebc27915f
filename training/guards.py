"""What `amfe train` refuses: bad data before training, a diverged network after it.

A model trained on a NaN pixel, a label at 1e300 or with a learning rate
that blew the weights up used to be written like any other (its metrics NaN,
or Ex predicted at 3e39 Pa). Now:

- :func:`check_data`, before training, on the rows it will use (and on a
  ``--test`` set): every input pixel finite, the fill (volume-fraction)
  channels in [0, 1] (to 1e-6, as ``amfe dataset --check``), the bond
  channels >= 0; no ok record with a non-finite label; the labels physical:
  moduli positive and within a factor :data:`MODULUS_SPREAD` of their
  column's median (a data set holds beds of one scale: moduli span a factor
  of about 30), and every Poisson ratio that of a positive-definite
  orthotropic compliance, nu_ij^2 < E_i / E_j (nu_yz^2 < Ey/Ez, nu_xz^2 <
  Ex/Ez, nu_xy^2 < Ex/Ey, with nu_ij = -S_ji / S_ii as in
  amfe.model.averages). Each refusal names rows and values.
- :func:`check_epoch`, after every epoch: a non-finite training or
  validation loss stops training (it never recovers).
- :func:`check_fit`, at the end: the ensemble's validation error, per
  property, as the mean squared error of its normalised predictions
  against that of predicting the training mean (normalised 0). More than
  :data:`DIVERGED_FACTOR` times that (and more than that times the training
  labels' variance, 1 in normalised units, so that a few validation beds
  near the mean cannot fail a model), or a non-finite prediction, is an
  error; above 1, a warning (a network that has learned nothing yet scores
  about 1: 0.94-1.06 after 1-5 epochs on tiny synthetic and real sets).
"""
import math

import numpy as np

from amfe.errors import AmfeError
from amfe.vocab import LABEL_NAMES

MODULUS_SPREAD = 1e3
"""A modulus further than this factor from its column's median is refused as absurd."""
DIVERGED_FACTOR = 2.0
"""A property whose validation error exceeds this many times that of the training mean's
prediction means training diverged (measured: 1e4-1e22 times at --lr 1 and 1e6)."""
PIXEL_SLACK = 1e-6     # volume fractions may exceed [0, 1] by float32 rounding
# Poisson ratio k (nu_yz, nu_xz, nu_xy) -> the moduli (i, j) of its bound nu_ij^2 < E_i / E_j
POISSON_PAIRS = ((1, 2), (0, 2), (0, 1))
LR_HINT = "lower --lr (lr=), or check the data set"


def _rows(rows, bad, limit=5):
    rows = np.asarray(rows)[bad]
    more = f" (+{rows.size - limit} more)" if rows.size > limit else ""
    return ", ".join(str(int(r)) for r in rows[:limit]) + more


def check_data(path, rows, images, labels, n_fill):
    """AmfeError unless the images (n, channels, H, W) and labels (n, 6) of ``rows`` (n,) of the
    data set ``path`` are fit to train on or to evaluate (see the module doc).

    The first ``n_fill`` channels are volume fractions, the rest bond images.
    """
    images, labels = np.asarray(images), np.asarray(labels, np.float64)
    if not len(rows):
        return
    flat = images.reshape(images.shape[0], images.shape[1], -1)
    bad = ~np.isfinite(flat).all(axis=(1, 2))
    if bad.any():
        raise AmfeError(f"{path}: records at rows {_rows(rows, bad)} have non-finite pixels "
                        "(NaN or inf) in their input images; regenerate those records or leave "
                        "them out (amfe dataset --check lists such problems)")
    fill, bonds = flat[:, :n_fill], flat[:, n_fill:]
    bad = (fill.min(axis=(1, 2)) < -PIXEL_SLACK) | (fill.max(axis=(1, 2)) > 1 + PIXEL_SLACK)
    if bad.any():
        raise AmfeError(f"{path}: records at rows {_rows(rows, bad)} have volume fractions "
                        "outside [0, 1] in their fill images; these are not amfe images")
    if bonds.size and (bad := bonds.min(axis=(1, 2)) < 0).any():
        raise AmfeError(f"{path}: records at rows {_rows(rows, bad)} have negative bond "
                        "stiffnesses in their bond images; these are not amfe images")
    check_labels(path, rows, labels)


def check_labels(path, rows, labels):
    """AmfeError unless labels (n, 6) are finite, moduli positive and near their median, and the
    Poisson ratios those of a positive-definite compliance (module doc)."""
    check_ok_records(path, np.asarray(rows)[~np.isfinite(labels).all(axis=1)])
    moduli = labels[:, :3]
    bad = (moduli <= 0).any(axis=1)
    if bad.any():
        raise AmfeError(f"{path}: records at rows {_rows(rows, bad)} have non-positive moduli "
                        f"({_values(labels, bad)}); a modulus is positive")
    median = np.median(moduli, axis=0)
    bad = (np.abs(np.log(moduli / median)) > math.log(MODULUS_SPREAD)).any(axis=1)
    if bad.any():
        raise AmfeError(f"{path}: records at rows {_rows(rows, bad)} have moduli more than "
                        f"{MODULUS_SPREAD:g} times from their median ({_values(labels, bad)}; "
                        f"medians Ex, Ey, Ez {', '.join(f'{m:.3g}' for m in median)} Pa): not "
                        "beds of this data set's scale; fix or remove those records")
    for k, (i, j) in enumerate(POISSON_PAIRS):
        bad = labels[:, 3 + k] ** 2 >= moduli[:, i] / moduli[:, j]
        if bad.any():
            raise AmfeError(
                f"{path}: records at rows {_rows(rows, bad)} have {LABEL_NAMES[3 + k]} "
                f"{labels[bad, 3 + k][0]:.3g}, no compliance of positive energy has: "
                f"{LABEL_NAMES[3 + k]}^2 must stay below {LABEL_NAMES[i]}/{LABEL_NAMES[j]} "
                f"({moduli[bad, i][0] / moduli[bad, j][0]:.3g} there); fix or remove those records")


def check_ok_records(path, rows):
    """AmfeError when ``rows`` (records with status ok but a non-finite label) is not empty."""
    if len(rows):
        raise AmfeError(f"{path}: ok records at rows {_rows(rows, slice(None))} have non-finite "
                        "labels; an ok record holds six finite constants (mark it failed, or "
                        "regenerate it)")


def _values(labels, bad):
    first = labels[np.flatnonzero(bad)[0]]
    return "the first: " + ", ".join(f"{n} {v:.3g}" for n, v in zip(LABEL_NAMES[:3], first[:3]))


def check_epoch(label, epoch, train_loss, val_loss, lr):
    """AmfeError when an epoch's training or validation loss is not finite."""
    for name, value in (("training", train_loss), ("validation", val_loss)):
        if value is not None and not math.isfinite(value):
            raise AmfeError(f"training diverged: {label + ', ' if label else ''}epoch {epoch}: "
                            f"{name} loss {value} at learning rate {lr:g}; {LR_HINT}. No model "
                            "was written")


def check_train_loss(label, loss, labels, norm, cfg):
    """Without validation beds: AmfeError when the last epoch's training ``loss`` exceeds
    :data:`DIVERGED_FACTOR` times that of predicting the mean of ``labels`` (n, 6)."""
    import torch  # noqa: PLC0415 (heavy or optional: loaded when used)

    z = norm.encode(labels)
    fn = {"mse": torch.nn.functional.mse_loss, "l1": torch.nn.functional.l1_loss}[cfg.loss]
    base = max(float(fn(torch.zeros_like(z), z)), 1e-12)
    if loss > DIVERGED_FACTOR * base:
        raise AmfeError(f"training diverged: {label + ': ' if label else ''}the last epoch's "
                        f"training loss {loss:.3g} is {loss / base:.3g} times that of predicting "
                        f"the mean (limit {DIVERGED_FACTOR:g}; learning rate {cfg.lr:g}); "
                        f"{LR_HINT}. No model was written")


def check_fit(pred, labels, norm, lr, log=None):
    """Per-property ratios of the validation error of ``pred`` (n, 6) to that of predicting the
    training mean, for ``labels`` (n, 6) under the normaliser ``norm``.

    AmfeError for a non-finite prediction or a ratio above :data:`DIVERGED_FACTOR` (with an
    error above that many training variances: module doc); ``log`` gets a warning line for a
    ratio above 1. Returns the six ratios.
    """
    pred = np.asarray(pred, np.float64)
    if not np.isfinite(pred).all():
        n = int(np.sum(~np.isfinite(pred).all(axis=1)))
        raise AmfeError(f"training diverged: the model's predictions of {n} validation beds are "
                        f"not finite (learning rate {lr:g}); {LR_HINT}. No model was written")
    z = norm.encode(labels).double().numpy()
    zp = norm.encode(np.where(norm.log.numpy(), np.maximum(pred, np.finfo(float).tiny), pred))
    err = ((zp.double().numpy() - z) ** 2).mean(axis=0)
    base = np.maximum((z ** 2).mean(axis=0), 1e-12)
    ratio = err / base
    # diverged: worse than the mean by the factor on these beds, and by as much against the
    # training labels' own spread (1 in normalised units), so that two validation beds that
    # happen to lie at the mean cannot fail a model that learned
    diverged = (ratio > DIVERGED_FACTOR) & (err > DIVERGED_FACTOR)
    if diverged.any():
        worst = int(np.argmax(np.where(diverged, ratio, -np.inf)))
        raise AmfeError(f"training diverged: the validation error of {LABEL_NAMES[worst]} is "
                        f"{ratio[worst]:.3g} times that of predicting the training mean (limit "
                        f"{DIVERGED_FACTOR:g}; learning rate {lr:g}); {LR_HINT}. No model was "
                        "written")
    worst = int(np.argmax(ratio))
    if ratio[worst] > 1 and log is not None:
        log(f"warning: the validation error of {LABEL_NAMES[worst]} is {ratio[worst]:.3g} times "
            "that of predicting the training mean: the model has not learned it yet (train "
            "longer)")
    return [float(r) for r in ratio]

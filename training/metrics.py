"""Error measures of predicted labels, per property (the paper's "average difference", and R^2)."""
import numpy as np

from amfe.training.guards import check_fit
from amfe.vocab import LABEL_NAMES


def relative_errors(pred, true):
    """|pred - true| / |true| per bed and property, (n, 6)."""
    pred, true = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    return np.abs(pred - true) / np.abs(true)


def property_metrics(pred, true):
    """{property: {mre, median_re, p95_re, max_re, r2, n}} over the beds (relative errors, not %).

    mre: mean of |pred - true| / |true|; R^2 = 1 - sum (pred - true)^2 /
    sum (true - mean(true))^2.
    """
    pred, true = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    rel = relative_errors(pred, true)
    out = {}
    for j, name in enumerate(LABEL_NAMES):
        ss_res = float(np.sum((pred[:, j] - true[:, j]) ** 2))
        ss_tot = float(np.sum((true[:, j] - true[:, j].mean()) ** 2))
        out[name] = {"mre": float(rel[:, j].mean()), "median_re": float(np.median(rel[:, j])),
                     "p95_re": float(np.percentile(rel[:, j], 95)),
                     "max_re": float(rel[:, j].max()),
                     "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
                     "n": int(true.shape[0])}
    return out


def validation_metrics(res, labels, norm, lr, log=None):
    """The validation block of a checkpoint's metrics from an ensemble prediction ``res``
    (Surrogate.predict's dict) of ``labels`` (n, 6): :func:`property_metrics`, the flagged
    fraction, and error_vs_mean, the six ratios of the error to that of predicting the
    training mean; AmfeError when training diverged (:func:`amfe.training.guards.check_fit`).
    """

    vs_mean = check_fit(res["mean"], labels, norm, lr, log)
    out = property_metrics(res["mean"], labels)
    out["flagged_fraction"] = float(np.mean(res["flagged"]))
    out["error_vs_mean"] = vs_mean
    return out


def metrics_line(metrics, key="mre", scale=100.0, fmt="{:.2f}"):
    """'Ex 1.23 Ey ...' of one metric over the six properties."""
    return " ".join(f"{n} {fmt.format(metrics[n][key] * scale)}" for n in LABEL_NAMES)

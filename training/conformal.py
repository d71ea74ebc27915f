"""Prediction intervals by split conformal prediction, per bed size.

Calibration (:func:`calibrate`) takes held-out beds of one size, never used
in training or model selection: predictions p (n, k), labels y (n, k) and
optionally the ensemble's relative spread s (n, k). The score of a bed and
constant is its normalised residual

    r = |y - p| / (|p| (s + s0)),

s0 the median spread on the calibration beds (1 when there is no spread, a
single network: r is then the relative residual |y - p| / |p|). For nominal
coverage 1 - a, q is the ceil((n + 1)(1 - a))-th smallest of the n scores
(infinite when that exceeds n: too few beds for the coverage), and a new
bed's interval is p -/+ q |p| (s + s0). If the calibration and new beds are
exchangeable, each constant's interval holds its label with probability at
least 1 - a (and below 1 - a + 1/(n + 1)): the guarantee is marginal, over
beds, per constant.

The checkpoint stores ``conformal``: {"coverage": 0.9, "names": [...],
"sizes": {size key: {"n", "quantile": {name: q}, "spread_scale": {name: s0},
"uses_spread"}}},
size keys from :func:`size_key` (the cropped in-plane size in mm, e.g.
"0.6x0.6"). A size without calibration gets no interval (:func:`interval_block`
says so). An interval wider than ``flag_half_width`` (relative half-width,
default 0.1) flags the bed.
"""
import math

import numpy as np

from amfe.errors import AmfeError

DEFAULT_COVERAGE = 0.9
DEFAULT_FLAG_HALF_WIDTH = 0.10


def size_key(size):
    """The calibration key of an in-plane size (x, y, ...) [m]: "0.6x0.6", "3x3" (mm, to 0.01)."""
    return "x".join(f"{round(float(s) * 1e3, 2):g}" for s in size[:2])


def _scale(pred, spread, s0):
    spread = np.zeros_like(pred) if spread is None else np.asarray(spread, np.float64)
    return np.abs(pred) * (spread + s0)


def calibrate(pred, labels, names, spread=None, coverage=DEFAULT_COVERAGE, offset=True):
    """{n, quantile {name: q}, spread_scale {name: s0}} of one size's held-out beds.

    pred, labels (n, k) [Pa, -]; spread (n, k) relative or None; coverage in (0, 1).
    offset False: s0 = 0, the score |y - p| / (|p| s), for a spread that is itself a scale
    of the error (the flag's error network's, amfe.training.flagrisk), positive everywhere.
    """
    pred, labels = np.asarray(pred, np.float64), np.asarray(labels, np.float64)
    if pred.shape != labels.shape or pred.ndim != 2 or pred.shape[1] != len(names):
        raise AmfeError(f"calibrate: predictions {pred.shape} and labels {labels.shape} must both "
                        f"be (beds, {len(names)})")
    if not 0.0 < float(coverage) < 1.0:
        raise AmfeError(f"calibrate: coverage must lie in (0, 1), got {coverage}")
    if not (np.isfinite(pred).all() and np.isfinite(labels).all()):
        raise AmfeError("calibrate: predictions and labels must be finite")
    n = pred.shape[0]
    if spread is None:
        s0 = np.ones(len(names))
    else:
        s0 = np.median(np.asarray(spread, np.float64), axis=0)
        s0 = np.where(s0 > 0, s0, 1.0) if offset else np.zeros(len(names))
    scores = np.abs(labels - pred) / np.maximum(_scale(pred, spread, s0), np.finfo(float).tiny)
    rank = math.ceil((n + 1) * float(coverage))
    q = np.sort(scores, axis=0)[rank - 1] if rank <= n else np.full(len(names), np.inf)
    return {"n": int(n), "quantile": {k: float(v) for k, v in zip(names, q)},
            "spread_scale": {k: float(v) for k, v in zip(names, s0)},
            "uses_spread": spread is not None}


def calibration(per_size, coverage=DEFAULT_COVERAGE, names=None,
                flag_half_width=DEFAULT_FLAG_HALF_WIDTH):
    """The checkpoint's ``conformal`` entry from {size key: calibrate(...)}."""
    return {"coverage": float(coverage), "names": list(names or []),
            "flag_half_width": float(flag_half_width),
            "score": "|label - prediction| / (|prediction| (spread + spread_scale))",
            "sizes": dict(per_size)}


def store(ckpt, key, cal, coverage, names, flag_half_width=None):
    """Add one size's calibration ``cal`` to ``ckpt["conformal"]`` (in place; returns ckpt).

    AmfeError if the checkpoint's calibration is at another nominal coverage.
    """
    conf = ckpt.get("conformal")
    if conf is None:
        conf = calibration({}, coverage, names,
                           DEFAULT_FLAG_HALF_WIDTH if flag_half_width is None else flag_half_width)
    elif abs(float(conf["coverage"]) - float(coverage)) > 1e-12:
        raise AmfeError(f"the model's intervals are calibrated at coverage {conf['coverage']:g}, "
                        f"not {float(coverage):g}; calibrate every size at one coverage")
    elif flag_half_width is not None:
        conf["flag_half_width"] = float(flag_half_width)
    conf["sizes"][key] = cal
    ckpt["conformal"] = conf
    return ckpt


def intervals(pred, names, cal, spread=None):
    """lo, hi (n, k) of predictions (n, k) with one size's calibration ``cal``."""
    pred = np.asarray(pred, np.float64)
    q = np.array([cal["quantile"][k] for k in names])
    s0 = np.array([cal["spread_scale"][k] for k in names])
    half = q * _scale(pred, spread, s0)
    return pred - half, pred + half


def interval_block(pred_row, names, conformal, size, spread_row=None):
    """A bed's {intervals {name: [lo, hi]} or None, coverage, calibration, interval_flag}.

    Without a calibration for the bed's size (or no ``conformal`` at all) the
    intervals and coverage are None and ``calibration`` says why.
    """
    key = size_key(size)
    cal = (conformal or {}).get("sizes", {}).get(key)
    if cal is None:
        why = ("the model has no conformal calibration" if not conformal else
               f"no calibration beds of size {key} mm (calibrated: "
               f"{', '.join(conformal['sizes']) or 'none'})")
        return {"intervals": None, "coverage": None, "interval_flag": False,
                "calibration": {"size": key, "n": 0, "note": f"no interval claimed: {why}"}}
    pred = np.asarray(pred_row, np.float64)[None]
    use = spread_row is not None and cal.get("uses_spread", False)
    spread = np.asarray(spread_row, np.float64)[None] if use else None
    lo, hi = intervals(pred, names, cal, spread)
    half = (hi - lo)[0] / 2 / np.maximum(np.abs(pred[0]), np.finfo(float).tiny)
    limit = float(conformal.get("flag_half_width", DEFAULT_FLAG_HALF_WIDTH))
    return {"intervals": {k: [float(a), float(b)] for k, a, b in zip(names, lo[0], hi[0])},
            "coverage": float(conformal["coverage"]),
            "interval_flag": bool(np.any(~np.isfinite(half) | (half > limit))),
            "calibration": {"size": key, "n": int(cal["n"]), "flag_half_width": limit}}

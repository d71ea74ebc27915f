"""One flag that holds bed by bed: a bed's risk of a constant more than 10 % off (issue 46).

The risk is a logistic model of "some constant more than 10 % off" on
features a prediction already has: the bed's fill and bond images (their
densities, the share of empty cells, the weakest cross-sections, the connected
pieces of the fill and whether the largest spans the bed: beds with skipped scan
pieces are where the surrogate errs) and the ensemble's spread and predicted
constants. It is fitted on held-out calibration beds (never trained on), and a
bed is flagged when its risk exceeds the threshold that flags a stated share of
the calibration beds (docs/surrogate.md, "The flag").

Intervals are Mondrian split-conformal: the calibration beds are split into
bins, by whether the bed looks as if it has skipped scan pieces (a second
logistic model on the same features, fitted to the generator's record of
skipped pieces: 88 % right on held-out beds) and by risk (:data:`BIN_EDGES`,
quantiles of the calibration risk, and the flag's threshold); each bin has
its own quantile per constant (amfe.training.conformal.calibrate; a bin with too few
calibration beds for the coverage takes its risk bin's over both kinds of bed), so the
coverage holds within each bin, not only over all beds: a risky bed gets the
wide interval of the risky beds, and beds with and without skipped pieces
each get their own. Within a bin the score is normalised by the ensemble's
spread (plus its median), or (``interval_from`` "flagnet") by the error network's
own scale of each constant's error, ``b`` of its Laplace distribution, alone: an
interval as wide as the network expects this bed's error to be, whose coverage
holds on each kind of bed the network tells apart (docs/surrogate.md, "The flag").

The model is a small JSON file beside the checkpoint (``flag_<scale>.json``,
amfe/models/), read by :func:`load_flag`. Version 2 adds the flag's error network
(amfe.training.flagnet; its file named by the flag file's ``flagnet``, beside it):
the logit of "some constant more than 10 % off" that it reads off the bed's images
is one more feature, and with ``risk_from`` "flagnet" it is the risk itself (the
logistic model then only guesses skipped pieces for the interval bins): on held-out
beds it ranks the bad beds better than the logistic on the summaries does with it
(docs/surrogate.md, "The flag"). With ``corrects`` the network also corrects the
constants (:func:`corrected`: by its location of each constant's error), and the risk
is then that of the corrected constants.
"""
import json
import os

import numpy as np
from scipy import ndimage

from amfe.errors import AmfeError
from amfe.training.conformal import calibrate
from amfe.training.flagnet import SCALE, bad_logit, flagnet_beside
from amfe.vocab import LABEL_NAMES

#: The format of the flag file (version 1: no error network; still read).
FLAG_FORMAT, FLAG_VERSION = "amfe.flag", 2
#: A constant this far off (relative) makes a bed bad.
BAD = 0.10
#: Risk bins of the intervals, as quantiles of the calibration risk (the last bin is the
#: flagged share when the flag's share is 1 - its edge).
BIN_EDGES = (0.5,)
#: The calibration risk's quantiles that the flag file keeps (every percent), from which
#: another flagged share's threshold is read (:func:`threshold_for`).
RISK_TABLE = np.linspace(0.0, 1.0, 101)
#: The shipped flag models read so far in this process, by (file, mtime): :func:`shipped_flag`.
_SHIPPED = {}


def features(fill, bonds, mean, spread, bond_scale):
    """(n, F) risk features of n beds: fill, bonds (n, layers, H, W) images; mean, spread
    (n, 6) the ensemble's predictions [Pa, -] and relative spread; bond_scale: the bond
    images' unit (the calibration beds' mean; the model file's ``bond_scale``). Beds of
    another E: give the bonds and moduli at the model's E (divided by E / E_model)."""
    fill, bonds = np.asarray(fill, float), np.asarray(bonds, float)
    n = len(fill)
    F = [fill.mean((1, 2, 3))] + [fill[:, k].mean((1, 2)) for k in range(fill.shape[1])]
    F += [(fill < t).mean((1, 2, 3)) for t in (0.05, 0.3, 0.6)]
    bn = bonds / float(bond_scale)
    F += [bn.mean((1, 2, 3))] + [bn[:, k].mean((1, 2)) for k in range(bonds.shape[1])]
    F.append((bn < 1e-3).mean((1, 2, 3)))
    cols, rows = bn.sum(2), bn.sum(3)     # per layer: sums over y (n, L, W), over x (n, L, H)
    F.append(cols.min(2).min(1) / (cols.mean((1, 2)) + 1e-12))
    F.append(rows.min(2).min(1) / (rows.mean((1, 2)) + 1e-12))
    layer = bn.sum((2, 3))
    F.append(layer.min(1) / (layer.mean(1) + 1e-12))
    for thr in (0.15, 0.35):
        F += [np.array(v, float) for v in zip(*(fill_pieces(fill[i], thr) for i in range(n)))]
    spread, mean = np.asarray(spread, float), np.asarray(mean, float)
    F += [np.log(spread[:, k] + 1e-6) for k in range(6)]
    F += [mean[:, k] for k in range(3, 6)] + [np.log(mean[:, k]) for k in range(3)]
    return np.stack(F, axis=1)


def with_flagnet(X, net, fill, bonds, bad=BAD, outputs=None, corrects=False):
    """X (n, F) and, as its last column, the error network ``net``'s logit of a bed being
    bad (amfe.training.flagnet) from the images fill, bonds (n, layers, H, W) at the model's
    E; X itself when ``net`` is None. outputs: the network's (mu, logb) of these beds, if
    already at hand (:func:`flagnet_outputs`); corrects: the logit of the prediction
    corrected by the network's mu (:func:`corrected`), whose error is centred: mu = 0."""
    if net is None:
        return X
    mu, logb = flagnet_outputs(net, fill, bonds) if outputs is None else outputs
    logit = bad_logit(np.zeros_like(mu) if corrects else mu, logb, bad)
    return np.concatenate([X, logit[:, None]], axis=1)


def corrected(mean, mu):
    """(n, 6) the predictions ``mean`` (n, 6) [Pa, -] corrected by the error network's
    location mu (n, 6) of their relative error r = predicted / label - 1 (SCALE units):
    mean / (1 + mu SCALE), the label the network expects. Any E: a factor per constant."""
    return np.asarray(mean, float) / (1.0 + np.asarray(mu, float) * SCALE)


def flagnet_outputs(net, fill, bonds):
    """(mu, logb), each (n, 6), of the error network ``net`` on images fill, bonds (n,
    layers, H, W) at the model's E (amfe.training.flagnet.FlagNet.outputs)."""
    images = np.concatenate([np.asarray(fill, np.float32), np.asarray(bonds, np.float32)], 1)
    return net.outputs(images)


def network_scale(logb):
    """(n, 6) the error network's scale of each constant's relative error, b = exp(logb)
    in plain relative units (logb in amfe.training.flagnet.SCALE units)."""
    return np.exp(np.asarray(logb, float)) * SCALE


def model_features(model, fill, bonds, mean, spread, outputs=None):
    """The (n, F) features that the flag model ``model`` (:func:`load_flag`'s) reads."""
    X = features(fill, bonds, mean, spread, model["bond_scale"])
    return with_flagnet(X, model.get("flagnet_net"), fill, bonds, model["bad"], outputs,
                        model.get("corrects", False))


def fill_pieces(img, thr):
    """(log(1 + pieces), share of the fill outside the largest, it spans x, it spans y) of one
    bed's fill image (layers, H, W): its pieces above fill ``thr``."""
    m = img > thr
    lab, k = ndimage.label(m)
    if k == 0:
        return 0.0, 1.0, 0.0, 0.0
    sizes = ndimage.sum(img, lab, range(1, k + 1))
    big = lab == 1 + int(np.argmax(sizes))
    return (np.log1p(k), 1 - sizes.max() / max(img[m].sum(), 1e-12),
            float(big.any((0, 1))[0] and big.any((0, 1))[-1]),
            float(big.any((0, 2))[0] and big.any((0, 2))[-1]))


def _design(X, mu, sd):
    Z = (np.asarray(X, float) - mu) / sd
    return np.concatenate([np.ones((len(Z), 1)), Z, Z ** 2], axis=1)


def bad_beds(pred, labels):
    """(n,) bool: a constant more than :data:`BAD` off."""
    return (np.abs(pred - labels) / np.abs(labels) > BAD).any(axis=1)


def _logistic(A, target, lam):
    w = np.zeros(A.shape[1])
    for _ in range(50):     # Newton's method on the penalised log-likelihood
        p = 1 / (1 + np.exp(-(A @ w)))
        H = (A * (p * (1 - p))[:, None]).T @ A + lam * np.eye(len(w))
        w -= np.linalg.solve(H, A.T @ (p - target) + lam * w)
    return w


def fit(X, data, bond_scale, flag_share=0.19, lam=0.1, coverage=0.9, risk_from="logistic",
        network=None):
    """The flag model (a dict for the JSON file) from calibration beds.

    X (n, F) :func:`features` (with ``bond_scale``); data: (pred, labels, spread (n, 6),
    skipped (n,) bool: the generator skipped scan pieces). flag_share: the share of the
    calibration beds above the threshold; lam: the logistic fits' ridge penalty;
    coverage: the intervals' nominal coverage; network: the error network's reading of
    these beds, {"logb": (n, 6) its log scales (:func:`flagnet_outputs`) or None,
    "corrects": bool} or None: with logb, the intervals' scores are normalised by its
    scales alone (``interval_from`` "flagnet"), not by the ensemble's spread plus its
    median; with "corrects" the predictions are corrected by it (:func:`corrected`: pred
    is then the corrected one, and X's logit the centred one, :func:`with_flagnet`).
    """
    logb = (network or {}).get("logb")
    pred, labels, spread, skipped = data
    bad = bad_beds(pred, labels).astype(float)
    mu, sd = X.mean(axis=0), X.std(axis=0) + 1e-12
    A = _design(X, mu, sd)
    w = _logistic(A, bad, lam)
    w_skip = _logistic(A, np.asarray(skipped, float), 1.0)
    if risk_from not in ("logistic", "flagnet"):
        raise AmfeError(f"the flag's risk comes from 'logistic' or 'flagnet', not {risk_from!r}")
    score = A @ w if risk_from == "logistic" else np.asarray(X, float)[:, -1]
    threshold = float(np.quantile(score, 1 - flag_share))
    model = {"format": FLAG_FORMAT, "format_version": FLAG_VERSION, "bad": BAD,
             "bond_scale": float(bond_scale), "coverage": coverage, "flag_share": flag_share,
             "lam": lam, "risk_from": risk_from,
             "interval_from": "spread" if logb is None else "flagnet",
             "corrects": bool(network and network.get("corrects")),
             "mu": mu.tolist(), "sd": sd.tolist(),
             "w": w.tolist(), "w_skip": w_skip.tolist(), "threshold": threshold,
             "bin_edges": [float(np.quantile(score, q)) for q in BIN_EDGES] + [threshold],
             "n": int(len(X)), "bad_share": float(bad.mean()),
             "risk_quantiles": [float(np.quantile(score, q)) for q in RISK_TABLE]}
    bins = bins_of(model, X)
    scale = spread if logb is None else network_scale(logb)
    risk_bins = len(model["bin_edges"]) + 1

    def calibrated(rows):
        return calibrate(pred[rows], labels[rows], list(LABEL_NAMES), scale[rows], coverage,
                         offset=logb is None)

    model["bins"] = []
    for b in range(n_bins(model)):
        cal = calibrated(bins == b) if np.any(bins == b) else None
        if cal is None or not np.all(np.isfinite(list(cal["quantile"].values()))):
            # Too few calibration beds for the coverage (an infinite interval): the bin takes
            # its risk bin's quantiles over both kinds of bed.
            cal = {**calibrated(bins % risk_bins == b % risk_bins), "pooled": True}
        model["bins"].append(cal)
    return model


def risk(model, X):
    """(n,) risk scores (the logit of "a constant more than 10 % off") of features X: the
    logistic model's, or the error network's (X's last column) for a model fitted so."""
    if model.get("risk_from", "logistic") == "flagnet":
        return np.array(np.asarray(X, float)[:, -1])
    return _design(X, np.asarray(model["mu"]), np.asarray(model["sd"])) @ np.asarray(model["w"])


def check_share(share):
    """``share`` as a float, if a number strictly between 0 and 1; else AmfeError."""
    if isinstance(share, bool) or not isinstance(share, (int, float, np.floating)) \
            or not 0.0 < float(share) < 1.0:
        raise AmfeError(f"the flagged share must be a number between 0 and 1 (exclusive), "
                        f"got {share!r}")
    return float(share)


def threshold_for(model, share=None):
    """The risk above which a bed is flagged: the file's threshold (``share`` None), or the
    one that ``share`` (0 < share < 1) of the calibration beds exceed, read off the file's
    table of the calibration risk's percentiles (linear between them; exact at whole
    percents). A larger share flags more beds, each of lower risk: the held-out figures of
    each share are in docs/surrogate.md, "The flag"."""
    if share is None:
        return float(model["threshold"])
    share = check_share(share)
    table = model.get("risk_quantiles")
    if table is None:
        raise AmfeError("this flag model has no table of its calibration risk, so it flags "
                        "only its own share; recalibrate it (run/train/calibrate_flag.py)")
    return float(np.interp(1.0 - share, RISK_TABLE, table))


def n_bins(model):
    """How many interval bins: (skipped-looking or not) x (risk bins)."""
    return 2 * (len(model["bin_edges"]) + 1)


def bins_of(model, X):
    """(n,) the interval bin of each bed of features X: risk bin, plus the risk bins' count
    when the bed looks as if it has skipped pieces."""
    A = _design(X, np.asarray(model["mu"]), np.asarray(model["sd"]))
    looks_skipped = (A @ np.asarray(model["w_skip"])) > 0
    return np.digitize(risk(model, X), model["bin_edges"]) \
        + looks_skipped * (len(model["bin_edges"]) + 1)


def load_flag(path):
    """The flag model of a JSON file; AmfeError for another format or version."""
    try:
        with open(path) as f:
            model = json.load(f)
    except (OSError, json.JSONDecodeError) as exc:
        raise AmfeError(f"cannot read the flag model {path}: {exc}") from None
    if model.get("format") != FLAG_FORMAT or model.get("format_version") not in (1, 2):
        raise AmfeError(f"{path} is not an amfe flag model of version 1 or {FLAG_VERSION} "
                        f"(format {model.get('format')!r}, version "
                        f"{model.get('format_version')!r})")
    if model.get("flagnet"):
        model["flagnet_net"] = flagnet_beside(path, model["flagnet"])
    elif "flagnet" in (model.get("risk_from"), model.get("interval_from")) \
            or model.get("corrects"):
        raise AmfeError(f"{path}: its risk or intervals come from an error network but it "
                        f"names none")
    return model


def bed_risk(model, fill, bonds, mean, spread, share=None):
    """One bed's flag: {risk (the logit), threshold, flag_share, flagged, bin, calibration
    (its bin's conformal calibration), interval_scale {constant: the relative scale its
    bin's quantiles multiply: the ensemble's spread or the error network's b}, correction
    {constant: the factor that corrects the prediction, :func:`corrected`} or None (a flag
    that does not correct)}; fill, bonds (layers, H, W), mean, spread (6,) at the model's E;
    share: the calibration beds' share to flag (None: the file's, :func:`threshold_for`).
    The interval's bin is the file's whatever the share."""
    net = model.get("flagnet_net")
    outputs = None if net is None else flagnet_outputs(net, fill[None], bonds[None])
    X = model_features(model, fill[None], bonds[None], np.asarray(mean)[None],
                       np.asarray(spread)[None], outputs)
    score = float(risk(model, X)[0])
    b = int(bins_of(model, X)[0])
    threshold = threshold_for(model, share)
    scale = network_scale(outputs[1])[0] if model.get("interval_from") == "flagnet" \
        else np.asarray(spread, float)
    return {"risk": score, "threshold": threshold,
            "flag_share": float(model["flag_share"] if share is None else share),
            "flagged": bool(score > threshold), "bin": b, "calibration": model["bins"][b],
            "interval_scale": {k: float(v) for k, v in zip(LABEL_NAMES, scale)},
            "correction": {k: float(v) for k, v in zip(
                LABEL_NAMES, corrected(np.ones(6), outputs[0][0]))}
            if model.get("corrects") else None}


def shipped_flag(checkpoint_path, models_dir, shipped):
    """The flag model of a shipped checkpoint (``flag_<scale>.json`` beside it), or None for
    a checkpoint that is not one of ``shipped`` ({scale: file name}) or has no flag file."""
    for scale, name in shipped.items():
        path = os.path.join(models_dir, name)
        flag = os.path.join(models_dir, f"flag_{scale}.json")
        if os.path.isfile(flag) and os.path.isfile(path) \
                and os.path.samefile(path, checkpoint_path):
            # Read once a process (a batch asks bed by bed): its error network's weights are
            # most of the flag's time on one bed otherwise. The key holds the file's mtime.
            key = (os.path.realpath(flag), os.stat(flag).st_mtime_ns)
            if key not in _SHIPPED:
                _SHIPPED[key] = load_flag(flag)
            return _SHIPPED[key]
    return None


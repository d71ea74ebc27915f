"""Fit the small model's flag and risk-binned intervals (issue 46), and test them.

On calibration data sets (held out of training; `small` beds rebuilt from their
label tables), the shipped small model's predictions and the risk features
(amfe.training.flagrisk) fit the risk model; the threshold flags
``--flag-share`` of the calibration beds; each risk bin gets its own conformal
quantiles. On each test set: the share flagged, the recall of the bad beds (a
constant more than 10 % off), the share bad and unflagged, the whole
precision-recall curve, and the intervals' coverage on the beds with skipped
scan pieces and on the others, each against its binomial band.

    python -m run.train.calibrate_flag --calibration s8.h5 s9.h5 s16.h5 --test s17.h5 \
        -o amfe/models/flag_small.json --json flag_report.json [--model MODEL.pt] \
        [--flagnet amfe/models/flag_small_net.npz]

``--flagnet``: the risk also reads the flag's error network (amfe.training.flagnet,
run/train/train_flagnet.py), whose file must sit beside ``-o``; ``--intervals-from
flagnet`` normalises the intervals' scores by its scale of each constant's error
instead of the ensemble's spread; ``--correct`` corrects the predictions by its
location of each constant's error (amfe.training.flagrisk.corrected), and fits and
tests the flag and intervals on the corrected predictions.
"""
import os

import h5py
import numpy as np
import torch
from scipy.stats import binom

from amfe.training.conformal import intervals
from amfe.training.data import dataset_info, read_rows
from amfe.training.flagnet import load_flagnet
from amfe.training.flagrisk import (
    bad_beds,
    bins_of,
    corrected,
    features,
    fit,
    flagnet_outputs,
    network_scale,
    risk,
    threshold_for,
    with_flagnet,
)
from amfe.training.predict import Surrogate
from amfe.vocab import LABEL_NAMES
from run.common import ROOT, md_table, parser, write_json


def predicted(sur, path):
    """(fill, bonds, mean, spread, labels, skipped (n,) bool) of a data set's ok beds."""
    rows = dataset_info(path, sur.inputs)["ok"]
    images, labels = read_rows(path, rows, sur.inputs)
    res = sur.predict(images)
    with h5py.File(path, "r") as f:
        skipped = f["params"]["skip_fraction"][()][rows] > 0
    n_fill = sur.n_fill
    return (images[:, :n_fill], images[:, n_fill:], res["mean"], res["spread"], labels,
            skipped)


#: The flagged shares (of the calibration beds; ``amfe predict --flag-share``) whose held-out
#: figures the report gives.
SHARES = (0.19, 0.25, 0.30, 0.35, 0.40)


def band(n, p=0.9, level=0.99):
    """The central ``level`` binomial band of the covered share of n beds at coverage p."""
    lo, hi = binom.interval(level, n, p)
    return lo / n, hi / n


def flag_inputs(data, net, bond_scale, corrects):
    """(X, mean, outputs) of :func:`predicted`'s ``data``: the risk features (with the error
    network ``net``'s logit, when there is one), the predictions (corrected by the network
    with ``corrects``) and the network's (mu, logb) (None without one)."""
    fill, bonds, mean, spread = data[:4]
    outputs = None if net is None else flagnet_outputs(net, fill, bonds)
    X = with_flagnet(features(fill, bonds, mean, spread, bond_scale), net, fill, bonds,
                     outputs=outputs, corrects=corrects)
    return X, corrected(mean, outputs[0]) if corrects else mean, outputs


def evaluate(model, data, net=None):
    """Flag and coverage figures of one test set (``data``: :func:`predicted`'s; ``net``:
    the flag's error network, None for none)."""
    spread, labels, skipped = data[3:]
    X, mean, outputs = flag_inputs(data, net, model["bond_scale"], model.get("corrects"))
    if model.get("interval_from") == "flagnet":
        spread = network_scale(outputs[1])
    score = risk(model, X)
    flagged, bad = score > model["threshold"], bad_beds(mean, labels)
    bins = bins_of(model, X)
    covered = np.zeros(labels.shape, bool)
    for b, cal in enumerate(model["bins"]):
        rows = bins == b
        lo, hi = intervals(mean[rows], list(LABEL_NAMES), cal, spread[rows])
        covered[rows] = (labels[rows] >= lo) & (labels[rows] <= hi)
    groups = {}
    for name, rows in (("skipped pieces", skipped), ("no skipped pieces", ~skipped),
                       ("all", np.ones(len(bad), bool))):
        lo, hi = band(int(rows.sum()))
        cov = covered[rows].mean(axis=0)
        groups[name] = {"n": int(rows.sum()), "coverage": dict(zip(LABEL_NAMES, map(float, cov))),
                        "band": [lo, hi], "inside": bool(np.all((cov >= lo) & (cov <= hi)))}
    curve = []
    for share in np.linspace(0.0, 0.5, 26):
        f = score > (np.quantile(score, 1 - share) if share > 0 else np.inf)
        curve.append({**_caught(f, bad), "precision": float(bad[f].sum() / max(f.sum(), 1))})
    points = {}   # what amfe predict --flag-share S gives: the threshold from calibration
    for share in SHARES:
        f = score > threshold_for(model, share)
        points[f"{share:.2f}"] = {
            **_caught(f, bad), "bad_among_unflagged": float((bad & ~f).sum() / max((~f).sum(), 1))}
    error = dict(zip(LABEL_NAMES, map(float, (np.abs(mean - labels) / np.abs(labels)).mean(0))))
    return {"n": int(len(bad)), "bad": float(bad.mean()), "mean_error": error,
            **_caught(flagged, bad),
            "coverage": groups, "curve": curve, "operating_points": points}


def _caught(flagged, bad):
    """{flagged, recall, bad_unflagged}: the shares of beds flagged and of bad beds flagged,
    and the share of beds bad and unflagged, of (n,) bool masks."""
    return {"flagged": float(flagged.mean()),
            "recall": float(bad[flagged].sum() / max(bad.sum(), 1)),
            "bad_unflagged": float((bad & ~flagged).mean())}


def main():
    p = parser(__doc__)
    p.add_argument("--calibration", nargs="+", required=True)
    p.add_argument("--test", nargs="*", default=[])
    p.add_argument("--flag-share", type=float, default=0.19)
    p.add_argument("--lam", type=float, default=0.1)
    p.add_argument("-o", "--output", default=None, help="the flag model (JSON) to write")
    p.add_argument("--json", default=None, help="the test figures (JSON)")
    p.add_argument("--model", default=f"{ROOT}/amfe/models/multiscale_small.pt",
                   help="the small model whose flag is fitted (default: the shipped one)")
    p.add_argument("--flagnet", default=None, help="the flag's error network (.npz) to read")
    p.add_argument("--risk-from", choices=("logistic", "flagnet"), default="logistic",
                   help="the risk: the logistic model, or the error network's logit alone")
    p.add_argument("--intervals-from", choices=("spread", "flagnet"), default="spread",
                   help="the intervals' scale: the ensemble's spread, or the error network's")
    p.add_argument("--correct", action="store_true",
                   help="correct the predictions by the error network's location of their error")
    args = p.parse_args()
    net = load_flagnet(args.flagnet) if args.flagnet else None
    if net is not None and args.output and os.path.dirname(os.path.abspath(args.flagnet)) \
            != os.path.dirname(os.path.abspath(args.output)):
        p.error("--flagnet must sit in the folder of -o (the flag file names it beside itself)")
    if ("flagnet" in (args.risk_from, args.intervals_from) or args.correct) and net is None:
        p.error("--risk-from flagnet, --intervals-from flagnet and --correct need --flagnet")
    torch.set_num_threads(1)
    sur = Surrogate.load(args.model)
    parts = [predicted(sur, path) for path in args.calibration]
    fill, bonds, mean, spread, labels, skipped = (np.concatenate([q[k] for q in parts])
                                                  for k in range(6))
    bond_scale = float(bonds.mean())
    X, mean, outputs = flag_inputs((fill, bonds, mean, spread), net, bond_scale, args.correct)
    model = fit(X, (mean, labels, spread, skipped), bond_scale, flag_share=args.flag_share,
                lam=args.lam, risk_from=args.risk_from,
                network=None if net is None else {
                    "logb": outputs[1] if args.intervals_from == "flagnet" else None,
                    "corrects": args.correct})
    model["calibration"] = [str(p) for p in args.calibration]
    if net is not None:
        model["flagnet"] = os.path.basename(args.flagnet)
    if args.output:
        write_json(args.output, model)
    report, rows = {}, []
    for path in args.test:
        r = evaluate(model, predicted(sur, path), net)
        report[path] = r
        cov = r["coverage"]
        rows.append([path.rsplit("/", 1)[-1], r["n"], f"{100 * r['bad']:.1f}",
                     f"{100 * r['flagged']:.1f}", f"{r['recall']:.2f}",
                     f"{100 * r['bad_unflagged']:.2f}"]
                    + [("yes" if cov[g]["inside"] else "no") + f" ({cov[g]['n']})"
                       for g in ("skipped pieces", "no skipped pieces")])
    print(md_table(["test set", "beds", "bad (%)", "flagged (%)", "recall",
                    "bad and unflagged (%)", "coverage in band: skipped", "not skipped"], rows))
    print("\nThe flagged share chosen (--flag-share; its threshold from the calibration beds): "
          "flagged % / recall / bad and unflagged % / bad among the unflagged %")
    print(md_table(["test set"] + [f"share {s:.2f}" for s in SHARES], [
        [path.rsplit("/", 1)[-1]] + [
            "{:.1f} / {:.2f} / {:.1f} / {:.1f}".format(
                100 * q["flagged"], q["recall"], 100 * q["bad_unflagged"],
                100 * q["bad_among_unflagged"])
            for q in r["operating_points"].values()] for path, r in report.items()]))
    print("\nMean relative error % of the predictions the flag covers (corrected with --correct):")
    print(md_table(["test set"] + list(LABEL_NAMES), [
        [path.rsplit("/", 1)[-1]] + [f"{100 * v:.2f}" for v in r["mean_error"].values()]
        for path, r in report.items()]))
    for path, r in report.items():
        for g, c in r["coverage"].items():
            print(f"  {path.rsplit('/', 1)[-1]} {g}: " + ", ".join(
                f"{k} {100 * v:.1f}" for k, v in c["coverage"].items())
                + f" (band {100 * c['band'][0]:.1f}-{100 * c['band'][1]:.1f} %)")
    if args.json:
        write_json(args.json, {"model": args.output, "tests": report})


if __name__ == "__main__":
    main()

"""Calibrate a checkpoint's split conformal intervals on held-out data sets, one per bed size.

    python -m run.train.calibrate_intervals MODEL.pt HELDOUT.h5 [HELDOUT.h5 ...] -o OUT.pt
                                      [--coverage 0.9] [--flag-half-width 0.1] [--check TEST.h5]

Each data set holds beds of one size (its ``bed_size`` attribute) that no
training run or model selection used. The model predicts their images (its
test-time averaging and ensemble included), amfe.training.conformal.calibrate
takes the quantile of the scores at the nominal coverage, and the size's
calibration joins the checkpoint's ``conformal`` entry. The model is written
to OUT.pt, which may not be MODEL.pt: the shipped model is never rewritten.
Label rule: the model must predict the data sets' labels as they are, so
a rule-1 model (whose moduli are converted per bed from the bed's geometry)
is refused.
"""
import argparse
import os
import sys
from run.common import parser



def binomial_interval(k, n, level=0.95):
    """Clopper-Pearson interval of a proportion k / n (scipy's beta quantiles)."""
    from scipy.stats import beta
    a = (1 - level) / 2
    lo = beta.ppf(a, k, n - k + 1) if k > 0 else 0.0
    hi = beta.ppf(1 - a, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def coverage_numbers(sur, path):
    """Per constant of ``path``'s beds: {names, n, nominal, key (size), calibrated (beds),
    covered (k,) shares, binomial (k, 2) 95 % intervals, half_width (k,) median relative
    half-widths, all_inside (share of beds with every constant inside)}."""
    import numpy as np
    from amfe.errors import AmfeError
    from amfe.training.conformal import intervals, size_key
    from amfe.training.data import dataset_info
    info = dataset_info(path, sur.inputs)
    key = size_key(info["bed_size"])
    conf = sur.ckpt["conformal"]
    cal = conf["sizes"].get(key)
    if cal is None:
        raise AmfeError(f"{path}: beds of {key} mm, a size the model has no calibration for")
    names, pred, labels, spread = predictions(sur, path, info)
    lo, hi = intervals(pred, names, cal, spread if cal.get("uses_spread") else None)
    inside = (labels >= lo) & (labels <= hi)
    n = inside.shape[0]
    k = inside.sum(axis=0)
    return {"names": list(names), "n": int(n), "nominal": float(conf["coverage"]), "key": key,
            "calibrated": int(cal["n"]), "covered": (k / n).tolist(),
            "binomial": [list(binomial_interval(int(c), n)) for c in k],
            "half_width": np.median((hi - lo) / 2 / np.abs(pred), axis=0).tolist(),
            "all_inside": float(inside.all(axis=1).mean())}


def coverage_report(sur, path):
    """Markdown lines: per constant, the share of ``path``'s beds whose label lies in its
    interval, its 95 % binomial interval, whether the nominal coverage lies inside, and the
    median relative half-width."""
    c = coverage_numbers(sur, path)
    nominal = c["nominal"]
    lines = [f"coverage on {os.path.basename(path)} ({c['n']} beds of {c['key']} mm, nominal "
             f"{100 * nominal:g} %, calibrated on {c['calibrated']} beds):", "",
             "| constant | covered % | 95 % binomial interval | nominal inside | median half-width % |",
             "|---|---|---|---|---|"]
    for name, cov, (a, b), half in zip(c["names"], c["covered"], c["binomial"], c["half_width"]):
        lines.append(f"| {name} | {100 * cov:.1f} | {100 * a:.1f}-{100 * b:.1f} | "
                     f"{'yes' if a <= nominal <= b else 'no'} | {100 * half:.2f} |")
    lines.append(f"\nall {len(c['names'])} inside at once: {100 * c['all_inside']:.1f} % of the "
                 "beds (the guarantee is per constant)")
    return "\n".join(lines)


def predictions(sur, path, info):
    """(names, predictions (n, k), labels (n, k), the members' relative spread (n, k)) of the
    data set's ok beds: the six constants, or for a stiffness-head model the nine (the shear
    moduli's labels from /C)."""
    import numpy as np
    from amfe.training.data import read_rows
    from amfe.vocab import LABEL_NAMES
    images, labels = read_rows(path, info["ok"], sur.inputs)
    res = sur.predict(images)
    if "constants9" not in res:
        return LABEL_NAMES, res["mean"], labels, res["spread"]
    from amfe.training.stiffness import NINE, constants_from_stiffness
    from amfe.training.stiffness_fit import read_stiffness
    shear = constants_from_stiffness(read_stiffness(path, info["ok"]))[:, 6:]
    return NINE, res["constants9"], np.concatenate([labels, shear], axis=1), res["spread9"]


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("model")
    p.add_argument("data", nargs="+")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--coverage", type=float, default=0.9)
    p.add_argument("--flag-half-width", type=float, default=None)
    p.add_argument("--check", action="append", default=[], metavar="TEST.h5",
                   help="fresh held-out beds (repeat; never the calibration beds): print the "
                        "measured coverage per constant with its 95 %% binomial interval")
    args = p.parse_args(argv)
    import numpy as np
    from amfe.errors import AmfeError
    from amfe.training.checkpoint import save_checkpoint
    from amfe.training.conformal import calibrate, size_key, store
    from amfe.training.data import dataset_info
    from amfe.training.predict import Surrogate

    try:
        if os.path.abspath(args.output) == os.path.abspath(args.model):
            raise AmfeError("-o may not be the model: write the calibrated model to a new file")
        sur = Surrogate.load(args.model)
        if sur.label_rule < 2:
            raise AmfeError(f"{args.model} predicts label rule 1 converted per bed; calibrate a "
                            "model trained on the data sets' rule-2 labels")
        pooled = {}   # size -> [(pred, labels, spread)]: data sets of one size calibrate together
        for path in args.data:
            info = dataset_info(path, sur.inputs)
            if "bed_size" not in info:
                raise AmfeError(f"{path} has no bed_size attribute: its beds' size is unknown")
            names, pred, labels, spread = predictions(sur, path, info)
            spread = spread if sur.n_members > 1 else None
            pooled.setdefault(size_key(info["bed_size"]), []).append((pred, labels, spread))
        for key, parts in pooled.items():
            pred, labels = (np.concatenate([p[i] for p in parts]) for i in (0, 1))
            spread = None if parts[0][2] is None else np.concatenate([p[2] for p in parts])
            cal = calibrate(pred, labels, names, spread, args.coverage)
            store(sur.ckpt, key, cal, args.coverage, names, args.flag_half_width)
            print(f"size {key} mm: {cal['n']} beds of {len(parts)} data set(s), quantiles "
                  + " ".join(f"{k} {v:.3g}" for k, v in cal["quantile"].items()))
        save_checkpoint(args.output, sur.ckpt)
        for path in args.check:
            print(coverage_report(sur, path))
    except AmfeError as exc:
        print(f"calibrate_intervals: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

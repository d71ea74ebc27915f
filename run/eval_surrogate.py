"""Held-out errors of surrogate checkpoints, overall and by kind of bed (issue 13).

    python run/eval_surrogate.py MODEL.pt [MODEL.pt ...] --test HELDOUT.h5 [--test ...]
                                 [--json OUT.json] [--names a,b,...]

Per checkpoint and held-out file: the mean relative error |pred - true| / |true|
in % of each of the six constants over all ok beds, then over the beds with
and without skipped scan pieces, sparsely scanned beds (scanned fraction < 0.6)
and whole beds (no skips, scanned fraction >= 0.9); the gate (every constant
under 4 %) and the goal (moduli under 2 %, Poisson ratios under 3 %) are
marked. One torch thread, the whole file in one batch. Prints markdown tables.
"""
import argparse
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

GATE, GOAL = 0.04, (0.02, 0.02, 0.02, 0.03, 0.03, 0.03)


def groups_of(path, ok):
    """[(name, bool mask over the ok rows)] of the kinds of bed."""
    import h5py
    with h5py.File(path, "r") as f:
        skip = f["params/skip_fraction"][()][ok]
        cov = f["params/coverage"][()][ok]
    return [("all beds", np.ones(skip.shape, bool)), ("skipped pieces", skip > 0),
            ("no skipped pieces", skip == 0), ("scanned fraction < 0.6", cov < 0.6),
            ("no skips, scanned fraction >= 0.9", (skip == 0) & (cov >= 0.9))]


def evaluate(model, test, cache=None):
    """{group: {n, mre: [6 fractions]}} of checkpoint ``model`` on data-set file ``test``."""
    from amfe.training.data import dataset_info, read_rows
    from amfe.training.metrics import relative_errors
    from amfe.training.predict import Surrogate

    sur = Surrogate.load(model)
    cache = {} if cache is None else cache
    key = (test, tuple(sur.inputs))
    if key not in cache:
        ok = dataset_info(test, sur.inputs)["ok"]
        cache[key] = (ok, *read_rows(test, ok, sur.inputs))
    ok, images, labels = cache[key]
    err = relative_errors(sur.predict(images)["mean"], labels)
    return {name: {"n": int(m.sum()), "mre": err[m].mean(axis=0).tolist()}
            for name, m in groups_of(test, ok) if m.any()}


def verdict(mre):
    if all(e < g for e, g in zip(mre, GOAL)):
        return "goal"
    return "gate" if all(e < GATE for e in mre) else "-"


def table(results, test):
    """Markdown: one row per (model, kind of bed) on ``test``."""
    from amfe.vocab import LABEL_NAMES
    lines = [f"Held-out `{os.path.basename(test)}`, mean relative error %:", "",
             "| model | beds | n | " + " | ".join(LABEL_NAMES) + " | mean | met |",
             "|---|---|---|" + "---|" * (len(LABEL_NAMES) + 2)]
    for name, by_test in results.items():
        for group, r in by_test[test].items():
            e = r["mre"]
            lines.append(f"| {name} | {group} | {r['n']} | "
                         + " | ".join(f"{100 * x:.2f}" for x in e)
                         + f" | {100 * np.mean(e):.2f} | {verdict(e) if group == 'all beds' else ''} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", metavar="MODEL.pt")
    ap.add_argument("--test", action="append", required=True, metavar="HELDOUT.h5")
    ap.add_argument("--names", help="comma list of row names (default: file names)")
    ap.add_argument("--json", metavar="OUT.json", help="also write the numbers as JSON")
    args = ap.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    names = (args.names.split(",") if args.names
             else [os.path.splitext(os.path.basename(m))[0] for m in args.models])
    if len(names) != len(args.models):
        ap.error("--names needs one name per model")
    cache, results = {}, {}
    for name, model in zip(names, args.models):
        results[name] = {t: evaluate(model, t, cache) for t in args.test}
    for t in args.test:
        print(table(results, t), end="\n\n")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

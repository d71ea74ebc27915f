"""Held-out errors of surrogate checkpoints, overall and by kind of bed (issue 13).

    python -m run.train.eval_surrogate MODEL.pt [MODEL.pt ...] --test HELDOUT.h5 [--test ...]
                                 [--json OUT.json] [--names a,b,...] [--curve PNG]

Per checkpoint and held-out file: the mean relative error |pred - true| / |true|
in % of each of the six constants over all ok beds (and the share of beds with
any constant more than 10 % and 20 % off: the tail), then over the beds with
and without skipped scan pieces, sparsely scanned beds (scanned fraction < 0.6)
and whole beds (no skips, scanned fraction >= 0.9); the gate (every constant
under 4 %) and the goal (moduli under 2 %, Poisson ratios under 3 %) are
marked. One torch thread, the whole file in one batch. Prints markdown tables.

--curve: the models are one recipe trained on nested training sets; fit the
error of each constant on the first --test file as a N^-p (least squares in
log-log over the sizes given), print the fit and the extrapolated N at which
each constant reaches the gate and the goal, and draw the curve as a PNG.
"""
import argparse
import json
import os
import sys

import numpy as np
from run.common import parser


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


def rule1_factors(test, rows):
    """V_hull / V_box of records ``rows`` of data set ``test``, from the regenerated beds:
    what `amfe predict` multiplies a label-rule-1 checkpoint's moduli by (docs/model.md,
    section 5), so that such a model is scored on rule-2 labels as users get it."""
    import h5py
    from amfe.model.carrying import rule1_factor
    from amfe.model.scales import bed_for, get_scale, record_seed
    with h5py.File(test, "r") as f:
        scale, seed = get_scale(str(f.attrs["scale"])), int(f.attrs["seed"])
        index = f["index"][()][rows]
    out = np.empty(len(index))
    for n, k in enumerate(index):
        bed = bed_for(scale, record_seed(seed, int(k)))
        out[n] = rule1_factor(bed.centers, bed.radii, bed.attrs.get("size"))
    return out


def evaluate(model, test, cache=None):
    """{group: {n, mre: [6 fractions]}} of checkpoint ``model`` on data-set file ``test``."""
    import h5py
    from amfe.dataset.parts import label_rule
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
    pred = sur.predict(images)["mean"]
    if sur.label_rule < 2:
        with h5py.File(test, "r") as f:
            rule = label_rule(dict(f.attrs))
        if rule >= 2:   # a rule-1 model on rule-2 labels: converted per bed, as `amfe predict` does
            if (test, "factors") not in cache:
                cache[(test, "factors")] = rule1_factors(test, ok)
            pred[:, :3] *= cache[(test, "factors")][:, None]
    err = relative_errors(pred, labels)
    worst = err.max(axis=1)   # the tail: beds with any constant far off (issues 30, 34)
    return {name: {"n": int(m.sum()), "mre": err[m].mean(axis=0).tolist(),
                   "se": (err[m].std(axis=0, ddof=1) / np.sqrt(max(m.sum(), 1))).tolist()
                   if m.sum() > 1 else [0.0] * err.shape[1],
                   "tail10": float((worst[m] > 0.10).mean()),
                   "tail20": float((worst[m] > 0.20).mean())}
            for name, m in groups_of(test, ok) if m.any()}


def verdict(mre):
    if all(e < g for e, g in zip(mre, GOAL)):
        return "goal"
    return "gate" if all(e < GATE for e in mre) else "-"


def table(results, test):
    """Markdown: one row per (model, kind of bed) on ``test``."""
    from amfe.vocab import LABEL_NAMES
    lines = [f"Held-out `{os.path.basename(test)}`, mean relative error %:", "",
             "| model | beds | n | " + " | ".join(LABEL_NAMES)
             + " | mean | any > 10 % | any > 20 % | met |",
             "|---|---|---|" + "---|" * (len(LABEL_NAMES) + 4)]
    for name, by_test in results.items():
        for group, r in by_test[test].items():
            e = r["mre"]
            lines.append(f"| {name} | {group} | {r['n']} | "
                         + " | ".join(f"{100 * x:.2f}" for x in e)
                         + f" | {100 * np.mean(e):.2f} | {100 * r['tail10']:.1f} | {100 * r['tail20']:.1f}"
                         + f" | {verdict(e) if group == 'all beds' else ''} |")
    return "\n".join(lines)


def size_curve(sizes, results, test):
    """{constant: (a, p, N at the gate, N at the goal)} of mre = a N^-p over ``sizes``."""
    from amfe.vocab import LABEL_NAMES
    n = np.log(np.asarray(sizes, float))
    out = {}
    for j, name in enumerate(LABEL_NAMES):
        y = np.log([r[test]["all beds"]["mre"][j] for r in results])
        slope, icpt = np.polyfit(n, y, 1)
        p, a = -slope, np.exp(icpt)
        at = (lambda e: float((a / e) ** (1 / p)) if p > 0 else float("inf"))
        out[name] = (float(a), float(p), at(GATE), at(GOAL[j]))
    return out


def curve_report(sizes, results, test, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from amfe.vocab import LABEL_NAMES
    fit = size_curve(sizes, results, test)
    lines = ["| constant | " + " | ".join(f"{n} beds" for n in sizes)
             + " | fit a N^-p: p | N for 4 % | N for the goal |",
             "|---|" + "---|" * (len(sizes) + 3)]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    grid = np.geomspace(min(sizes), max(max(sizes) * 50, 1e5), 50)
    for j, name in enumerate(LABEL_NAMES):
        e = [100 * r[test]["all beds"]["mre"][j] for r in results]
        a, p, n_gate, n_goal = fit[name]
        lines.append(f"| {name} | " + " | ".join(f"{x:.2f}" for x in e)
                     + f" | {p:.2f} | {n_gate:,.0f} | {n_goal:,.0f} |")
        line, = ax.loglog(sizes, e, "o", label=name)
        ax.loglog(grid, 100 * a * grid ** -p, "--", color=line.get_color(), lw=0.8)
    ax.axhline(4, color="k", lw=0.8)
    ax.text(grid[-1], 4, "gate 4 %", ha="right", va="bottom", fontsize=8)
    ax.axhline(2, color="grey", lw=0.8, ls=":")
    ax.text(grid[-1], 2, "goal, moduli 2 %", ha="right", va="bottom", fontsize=8)
    ax.set_xlabel("training beds")
    ax.set_ylabel("held-out mean relative error, %")
    ax.set_title(f"one recipe on nested training sets; held-out {os.path.basename(test)}",
                 fontsize=9)
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:,.0f}"
                                                                 if v >= 1 else f"{v:g}"))
    ax.yaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(
        lambda v, _: f"{v:g}" if round(v) in (3, 6) else ""))
    ax.legend(ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    return "\n".join(lines)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("models", nargs="+", metavar="MODEL.pt")
    ap.add_argument("--test", action="append", required=True, metavar="HELDOUT.h5")
    ap.add_argument("--names", help="comma list of row names (default: file names)")
    ap.add_argument("--json", metavar="OUT.json", help="also write the numbers as JSON")
    ap.add_argument("--curve", metavar="PNG", help="error against training-set size (see above)")
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
    if args.curve:
        from amfe.training.checkpoint import load_checkpoint
        sizes = [load_checkpoint(m)["dataset"]["n_train"] for m in args.models]
        print(curve_report(sizes, [results[n] for n in names], args.test[0], args.curve))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

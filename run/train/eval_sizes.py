"""The surrogate's error against bed size: a table and a PNG (issue 34, docs/surrogate.md).

    .venv/bin/python -m run.train.eval_sizes --pair MODEL.pt TEST.h5 [--pair ...] \
        [--baseline-train TRAIN.h5 ...] [--png docs/surrogate_sizes.png]

Each --pair is the model that predicts one bed size and that size's held-out
test beds (never used to train, choose or calibrate it). Per size: the mean
relative error of each constant with its standard error, the tail (share of
beds with any constant more than 10 % off), the measured coverage of the
model's intervals (run/train/calibrate_intervals.py's report) and, with
--baseline-train, the density-and-size baseline's error on the same beds
(run/train/baseline_density.py). One torch thread.
"""
import argparse
import os
import sys

import numpy as np
from run.common import parser



def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--pair", nargs=2, action="append", required=True, metavar=("MODEL", "TEST"))
    p.add_argument("--baseline-train", action="append", default=[])
    p.add_argument("--png")
    args = p.parse_args(argv)
    import torch
    from run.train.baseline_density import fit, predict as baseline, read
    from run.train.calibrate_intervals import coverage_report
    from run.train.eval_surrogate import evaluate
    from amfe.training.predict import Surrogate
    from amfe.vocab import LABEL_NAMES
    torch.set_num_threads(1)
    coef = fit(args.baseline_train) if args.baseline_train else None
    rows = []
    print("| size | model | test beds | n | " + " | ".join(LABEL_NAMES) + " | any > 10 % |")
    print("|---|---|---|---|" + "---|" * (len(LABEL_NAMES) + 1))
    for model, test in args.pair:
        r = evaluate(model, test)["all beds"]
        d, side, y = read(test)
        size = f"{side[0]:g} mm"
        print(f"| {size} | `{os.path.basename(model)}` | `{os.path.basename(test)}` | {r['n']} | "
              + " | ".join(f"{100 * e:.2f} +- {100 * s:.2f}" for e, s in zip(r["mre"], r["se"]))
              + f" | {100 * r['tail10']:.1f} |")
        base = None
        if coef is not None:
            err = np.abs(baseline(coef, d, side) / y - 1)
            base = err.mean(axis=0)
            print(f"| {size} | density and size only | | {len(d)} | "
                  + " | ".join(f"{100 * e:.2f}" for e in base)
                  + f" | {100 * (err.max(axis=1) > 0.1).mean():.1f} |")
        rows.append((side[0], r["mre"], base))
    for model, test in args.pair:
        sur = Surrogate.load(model)
        if sur.ckpt.get("conformal"):
            print()
            print(coverage_report(sur, test))
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6.4, 3.8))
        width = 0.8 / len(rows)
        for k, (side, mre, _) in enumerate(rows):
            ax.bar(np.arange(6) + (k - (len(rows) - 1) / 2) * width, 100 * np.asarray(mre),
                   width, label=f"{side:g} mm beds")
        ax.axhline(4, color="k", lw=0.8)
        ax.text(5.5, 4.05, "gate 4 %", ha="right", va="bottom", fontsize=8)
        ax.set_xticks(np.arange(6), LABEL_NAMES)
        ax.set_ylabel("held-out mean relative error, %")
        ax.set_title("the surrogate by bed size (one fine-tuned network per size)", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.png, dpi=120)
        print(f"\nwrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

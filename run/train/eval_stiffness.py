"""Held-out errors of a stiffness-head model against a six-constant one on the same beds.

    .venv/bin/python -m run.train.eval_stiffness HELDOUT.h5 --model STIFF.pt [--baseline MODEL.pt]
                     [--tta flips|d4] [--json OUT.json]

For each model: the mean relative error of the six constants against the
data set's /labels; the tail (share of beds with any of the six more than
10 % and 20 % off). For the stiffness model also the three shear moduli
against those of the data set's /C (G = 1/S44, 1/S55, 1/S66,
amfe.training.stiffness.constants_from_stiffness), and the paired
difference of each constant's relative error (stiffness minus baseline, the
same beds) with its standard error. --baseline defaults to the shipped small
model.
"""
import argparse
import json
import sys

import numpy as np

from amfe.training.metrics import relative_errors as relative
from amfe.training.stiffness import NINE
from amfe.vocab import LABEL_NAMES as SIX
from run.common import parser

SHEAR = NINE[6:]


def evaluate(data, model_path, tta=None):
    """(relative errors (n, 6), shear relative errors (n, 3) or None, result dict)."""
    from amfe.training.data import dataset_info, read_rows
    from amfe.training.predict import Surrogate
    from amfe.training.stiffness import constants_from_stiffness
    from amfe.training.stiffness_fit import read_stiffness
    from amfe.training.checkpoint import load_checkpoint
    ckpt = load_checkpoint(model_path)
    if tta:
        ckpt["tta"] = tta
    sur = Surrogate(ckpt, model_path)
    rows = dataset_info(data, sur.inputs)["ok"]
    images, labels = read_rows(data, rows, sur.inputs)
    res = sur.predict(images)
    six = relative(res["mean"], labels)
    shear = None
    if "constants9" in res:
        true9 = constants_from_stiffness(read_stiffness(data, rows))
        shear = relative(res["constants9"][:, 6:], true9[:, 6:])
    return six, shear, res


def summary(six):
    worst = six.max(axis=1)
    return {"mre": {n: float(100 * six[:, k].mean()) for k, n in enumerate(SIX)},
            "mean": float(100 * six.mean()), "any_over_10": float(100 * (worst > 0.10).mean()),
            "any_over_20": float(100 * (worst > 0.20).mean()), "n": int(six.shape[0])}


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("data")
    p.add_argument("--model", required=True, help="the stiffness-head checkpoint")
    p.add_argument("--baseline", help="a six-constant checkpoint (default: the shipped small model)")
    p.add_argument("--tta", choices=("none", "flips", "d4"), help="override the stiffness model's")
    p.add_argument("--json")
    args = p.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    from amfe.training.predict import default_model_path
    base = args.baseline or str(default_model_path())
    s6, shear, _ = evaluate(args.data, args.model, args.tta)
    b6, _, _ = evaluate(args.data, base)
    diff = s6 - b6
    out = {"data": args.data, "model": args.model, "baseline": base, "tta": args.tta,
           "stiffness": summary(s6), "baseline_errors": summary(b6),
           "paired": {n: {"diff": float(100 * diff[:, k].mean()),
                          "se": float(100 * diff[:, k].std(ddof=1) / np.sqrt(len(diff)))}
                      for k, n in enumerate(SIX)}}
    if shear is not None:
        out["stiffness"]["shear_mre"] = {n: float(100 * shear[:, k].mean())
                                         for k, n in enumerate(SHEAR)}
    for name, block in (("stiffness", out["stiffness"]), ("baseline", out["baseline_errors"])):
        print(f"{name:10s} " + " ".join(f"{n} {block['mre'][n]:.2f}" for n in SIX)
              + f" | mean {block['mean']:.2f} | any>10% {block['any_over_10']:.1f} | "
              f"any>20% {block['any_over_20']:.1f} (n {block['n']})")
    print("paired     " + " ".join(f"{n} {v['diff']:+.2f}+-{v['se']:.2f}"
                                   for n, v in out["paired"].items()))
    if shear is not None:
        print("shear      " + " ".join(f"{n} {v:.2f}" for n, v in
                                       out["stiffness"]["shear_mre"].items()))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())

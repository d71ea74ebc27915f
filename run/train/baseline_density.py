"""The trivial surrogate: each constant from the bed's density and size alone (issue 34).

    .venv/bin/python -m run.train.baseline_density --train TRAIN.h5 [--train ...] \
        --test HELDOUT.h5 [--test ...]

Per constant, a least-squares fit on the training beds of

    log y = a0 + a1 log d + a2 (log d)^2 + a3 log(d) / L + a4 / L

(y the label, d the packing density of the image, L the bed's side in mm: the
KUBC boundary layer's share goes as 1/L), then the mean relative error and the
tail (any constant more than 10 % off) on each held-out file. It is the floor
the network's margin is measured from: what a bed's image adds beyond how
full it is and how big.
"""
import argparse
import os
import sys

import numpy as np
from run.common import parser



def features(density, side_mm):
    ld = np.log(density)
    inv = 1.0 / side_mm
    return np.stack([np.ones_like(ld), ld, ld ** 2, ld * inv, inv], axis=1)


def read(path):
    """(density (n,), side [mm] (n,), labels (n, 6)) of the ok records of a data set."""
    import h5py
    from amfe.training.data import dataset_info
    ok = dataset_info(path)["ok"]
    with h5py.File(path, "r") as f:
        d = f["density"][()][ok]
        y = f["labels"][()][ok]
        side = float(f.attrs["bed_size"][0]) * 1e3
    return d, np.full(d.shape, side), y


def fit(paths):
    parts = [read(p) for p in paths]
    d = np.concatenate([p[0] for p in parts])
    s = np.concatenate([p[1] for p in parts])
    y = np.concatenate([p[2] for p in parts])
    coef, *_ = np.linalg.lstsq(features(d, s), np.log(y), rcond=None)
    return coef


def predict(coef, density, side_mm):
    return np.exp(features(density, side_mm) @ coef)


def main(argv=None):
    from amfe.vocab import LABEL_NAMES
    p = parser(__doc__)
    p.add_argument("--train", action="append", required=True)
    p.add_argument("--test", action="append", required=True)
    args = p.parse_args(argv)
    coef = fit(args.train)
    print(f"density-and-size baseline fitted on {', '.join(map(os.path.basename, args.train))}")
    print("| held-out | n | " + " | ".join(LABEL_NAMES) + " | any > 10 % |")
    print("|---|---|" + "---|" * (len(LABEL_NAMES) + 1))
    for path in args.test:
        d, s, y = read(path)
        err = np.abs(predict(coef, d, s) / y - 1)
        print(f"| {os.path.basename(path)} | {len(d)} | "
              + " | ".join(f"{100 * e:.2f}" for e in err.mean(axis=0))
              + f" | {100 * (err.max(axis=1) > 0.1).mean():.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Physics upscaling against the per-size networks on the same held-out beds (issue 34, b).

    .venv/bin/python -m run.train.eval_upscale --train TRAIN.h5 --test TEST.h5
                     [--model amfe/models/stiffness_small.pt] [--sub 4 4 4] [--json OUT.json]

Each bed's image is cut into 0.6 mm tiles (20 x 20 pixels), the small stiffness model
predicts every tile's C, and a KUBC finite-element solve over the tiles gives the bed's C
(amfe.training.upscale). Printed, per constant, the mean relative error on the test beds:
- "tile mean": the tiles' C averaged (what a KUBC box one element high gives: Voigt);
- "coarse solve": the upscaled C as it is;
- "coarse solve, scaled": times one factor per constant, fitted on the training beds (the
  geometric mean of label / prediction): it takes out the KUBC stiffening that every tile's
  label carries (docs/surrogate.md, "Physics upscaling").
Neither data set is trained on; the test beds choose nothing.
"""
import argparse
import json
import sys
import time

import numpy as np

from amfe.training.metrics import relative_errors
from amfe.vocab import LABEL_NAMES as SIX
from run.common import parser

TILE_PX = 20
TILE_SIZE = (0.6e-3, 0.6e-3, 0.3e-3)   # m: a `small` bed, what the tiles' model knows


def upscale_set(sur, path, sub):
    """(labels (n, 6), tile-mean constants (n, 6), coarse constants (n, 6), seconds a bed)."""
    from amfe.training.data import dataset_info, read_rows
    from amfe.training.stiffness_predict import nine_constants
    from amfe.training.upscale import upscaled_stiffness
    rows = dataset_info(path, sur.inputs)["ok"]
    images, labels = read_rows(path, rows, sur.inputs)
    t0 = time.perf_counter()
    C, C_tiles = upscaled_stiffness(sur, images, TILE_PX, TILE_SIZE, sub)
    seconds = (time.perf_counter() - t0) / len(rows)
    mean = nine_constants(C_tiles.mean(axis=(1, 2)))[:, :6]
    return labels, mean, nine_constants(C)[:, :6], seconds


def scores(pred, labels):
    rel = relative_errors(pred, labels)
    return {"mre": {n: float(100 * rel[:, k].mean()) for k, n in enumerate(SIX)},
            "se": {n: float(100 * rel[:, k].std(ddof=1) / np.sqrt(len(rel)))
                   for k, n in enumerate(SIX)},
            "any_over_10": float(100 * (rel.max(axis=1) > 0.10).mean()), "n": len(rel)}


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--train", required=True, help="beds of the test size to fit the factors on")
    p.add_argument("--test", required=True)
    p.add_argument("--model", default="amfe/models/stiffness_small.pt")
    p.add_argument("--sub", type=int, nargs=3, default=(4, 4, 4),
                   help="hexahedra a tile along x, y, z (default 4 4 4)")
    p.add_argument("--json")
    args = p.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    from amfe.training.checkpoint import load_checkpoint
    from amfe.training.predict import Surrogate
    sur = Surrogate(load_checkpoint(args.model), args.model)
    y_tr, _, up_tr, _ = upscale_set(sur, args.train, args.sub)
    factor = np.exp(np.mean(np.log(y_tr / up_tr), axis=0))
    y, mean, up, sec = upscale_set(sur, args.test, args.sub)
    out = {"model": args.model, "train": args.train, "test": args.test, "sub": list(args.sub),
           "factor": dict(zip(SIX, map(float, factor))), "seconds_per_bed": sec,
           "tile mean": scores(mean, y), "coarse solve": scores(up, y),
           "coarse solve, scaled": scores(up * factor, y)}
    print(f"{args.test}: {out['coarse solve']['n']} beds; tiles of {TILE_PX} px, "
          f"sub {args.sub}; {sec:.2f} s a bed (network and coarse solve)")
    print(f"{'':22s}" + "".join(f"{n:>8s}" for n in SIX) + "  any>10%")
    for key in ("tile mean", "coarse solve", "coarse solve, scaled"):
        print(f"{key:22s}" + "".join(f"{out[key]['mre'][n]:8.2f}" for n in SIX)
              + f"  {out[key]['any_over_10']:6.1f}")
    print("factors: " + ", ".join(f"{n} {f:.3f}" for n, f in out["factor"].items()))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

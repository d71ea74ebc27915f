"""Merge separately trained members into one ensemble checkpoint (amfe.training.merge).

    .venv/bin/amfe train DATA.h5 --seed 0 -o a.pt ...    # on one core
    .venv/bin/amfe train DATA.h5 --seed 1 -o b.pt ...    # the same recipe, on another
    .venv/bin/python -m run.train.merge_members a.pt b.pt --data DATA.h5 -o ab.pt [--test HELDOUT.h5] [--tta flips]

The result is the checkpoint ``amfe train --seed 0 --members 2`` would have
written (the same members; the flag calibrated on the validation beds of
DATA.h5), usable by ``amfe predict --model ab.pt``.
"""
import argparse
import sys

from amfe.errors import AmfeError
from run.common import parser


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("checkpoints", nargs="+", help="the parts (.pt), two or more")
    p.add_argument("--data", required=True, help="the training data set of every part")
    p.add_argument("-o", "--output", required=True, help="the merged checkpoint (.pt)")
    p.add_argument("--test", help="also evaluate the merged model on this held-out data set")
    p.add_argument("--flag-percentile", type=float, default=95.0)
    p.add_argument("--tta", choices=("none", "flips", "d4"),
                   help="the merged model's test-time averaging (default: the members'); the "
                        "flag is calibrated with it")
    args = p.parse_args(argv)
    from amfe.training.checkpoint import load_checkpoint, save_checkpoint
    from amfe.training.merge import merge_members
    from amfe.training.metrics import metrics_line
    from amfe.training.predict import Surrogate
    from amfe.training.train import evaluate_file
    try:
        ckpts = [load_checkpoint(c) for c in args.checkpoints]
        if args.tta is not None:   # an inference setting: the members' weights do not depend on it
            for ck in ckpts:
                ck["tta"] = args.tta
        merged = merge_members(ckpts, args.data, args.flag_percentile, names=args.checkpoints)
        if args.test:
            m, _, _ = evaluate_file(Surrogate(merged, args.output), args.test)
            merged["metrics"]["test"] = dict(m, path=str(args.test))
        save_checkpoint(args.output, merged)
    except AmfeError as exc:
        print(f"merge_members: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.output}: {len(merged['members'])} members (seeds {merged['member_seeds']})")
    for key in ("validation", "test"):
        if key in merged["metrics"]:
            print(f"  {key}: mean relative error % {metrics_line(merged['metrics'][key])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

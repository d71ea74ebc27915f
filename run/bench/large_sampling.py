"""What the large beds' coarser sampling costs in accuracy (issue 46, item 5): each bed of a
data set predicted by `amfe.predict` twice, at the training's sample spacing and as amfe
predicts it (twice the spacing for a bed over a million sample lines,
amfe.training.imagebox.sample_spacing), paired.

    .venv/bin/python -m run.bench.large_sampling DATA.h5 [--count N] [--json OUT.json]

DATA.h5: a data set of one box scale (its beds are regenerated from their seeds, so a set
rebuilt by `amfe dataset --from-labels` serves). Prints, per constant, the mean relative
error against the labels at both samplings, their paired difference with its standard
error, the mean and largest relative change of the prediction, the 90 % intervals'
coverage, the flagged beds and those more than 10 % off and unflagged, and the median
seconds of a prediction. One torch thread.
"""
import json
import time

import numpy as np

from run.common import md_table, parser


def predictions(beds, labels, lines):
    """(constants (n, 6), covered (n, 6) bool, flagged (n,) bool, seconds (n,)) of amfe.predict
    with amfe.training.imagebox.MAX_SAMPLE_LINES set to ``lines`` (None: as shipped)."""
    import amfe
    import amfe.training.imagebox as imagebox
    from amfe.vocab import LABEL_NAMES
    keep = imagebox.MAX_SAMPLE_LINES
    imagebox.MAX_SAMPLE_LINES = keep if lines is None else lines
    try:
        out = ([], [], [], [])
        for bed, label in zip(beds, labels):
            t0 = time.perf_counter()
            p = amfe.predict(bed)
            out[3].append(time.perf_counter() - t0)
            if p.source != "surrogate":
                raise SystemExit(f"a bed was not predicted: {p}")
            out[0].append([p.properties[k] for k in LABEL_NAMES])
            iv = p.intervals or {}
            out[1].append([k in iv and iv[k][0] <= v <= iv[k][1]
                           for k, v in zip(LABEL_NAMES, label)])
            out[2].append(bool(p.flagged))
        return tuple(np.array(v) for v in out)
    finally:
        imagebox.MAX_SAMPLE_LINES = keep


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("data")
    ap.add_argument("--count", type=int, default=None)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    import h5py
    import torch

    from amfe.model.scales import bed_for
    from amfe.vocab import LABEL_NAMES
    torch.set_num_threads(1)
    with h5py.File(args.data, "r") as f:
        scale = f.attrs["scale"]
        scale = scale.decode() if isinstance(scale, bytes) else str(scale)
        ok = np.flatnonzero(f["status"][:] == 0)[:args.count]
        seeds, labels = f["seed"][:][ok], f["labels"][:][ok]
    beds = [bed_for(scale, int(s)) for s in seeds]
    fine = predictions(beds, labels, 10**18)
    coarse = predictions(beds, labels, None)
    e_f, e_c = (np.abs(p[0] / labels - 1) * 100 for p in (fine, coarse))
    d = e_c - e_f
    shift = np.abs(coarse[0] / fine[0] - 1) * 100
    n = len(seeds)
    res = {"data": args.data, "beds": n, "names": list(LABEL_NAMES),
           "error_training_sampling": e_f.mean(0).tolist(),
           "error_as_predicted": e_c.mean(0).tolist(),
           "paired_difference": d.mean(0).tolist(),
           "standard_error": (d.std(0, ddof=1) / np.sqrt(n)).tolist(),
           "mean_change": shift.mean(0).tolist(), "largest_change": shift.max(0).tolist(),
           "coverage": [fine[1].mean(0).tolist(), coarse[1].mean(0).tolist()],
           "flagged": [int(fine[2].sum()), int(coarse[2].sum())],
           "bad_unflagged": [int(((e.max(1) > 10) & ~p[2]).sum()) for e, p in
                             ((e_f, fine), (e_c, coarse))],
           "seconds": [float(np.median(fine[3])), float(np.median(coarse[3]))]}
    print(f"{args.data}: {n} beds of scale {scale}")
    rows = [[k, f"{a:.3f}", f"{b:.3f}", f"{c:+.4f} +- {s:.4f}", f"{m:.4f}", f"{x:.4f}",
             f"{100 * cf:.1f} / {100 * cc:.1f}"]
            for k, a, b, c, s, m, x, cf, cc in zip(
                LABEL_NAMES, *(res[key] for key in (
                    "error_training_sampling", "error_as_predicted", "paired_difference",
                    "standard_error", "mean_change", "largest_change")), *res["coverage"])]
    print(md_table(["constant", "error % (training's sampling)", "error % (as predicted)",
                    "difference (points)", "mean change %", "largest change %",
                    "coverage % (training's / as predicted)"], rows))
    print(f"flagged: {res['flagged'][0]} / {res['flagged'][1]}; more than 10 % off and "
          f"unflagged: {res['bad_unflagged'][0]} / {res['bad_unflagged'][1]}; median seconds a "
          f"prediction: {res['seconds'][0]:.3f} / {res['seconds'][1]:.3f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

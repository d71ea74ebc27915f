"""Calibrate the size rule's intervals on beds of sizes between the shipped ones (issue 46).

The size rule (amfe.training.sizerule) predicts a bed of any side from the
shipped models; its intervals need calibration beds of sizes it interpolates
at, never the test sizes (0.9, 2 and 4 mm). The calibration sets given (steel,
3 layers: `amfe dataset --size X X 0.3`) are grouped by the span between two
shipped sizes their side lies in (0.6-1.2 mm; 1.2 mm and up), and each span's
scores pooled into one split-conformal calibration
(amfe.training.conformal.calibrate), written as
amfe/models/sizerule_calibration.json; `amfe predict` uses a span's at every
size in it without a shipped model.

    python -m run.train.calibrate_sizerule --sets cal16.h5 cal25.h5 \
        -o amfe/models/sizerule_calibration.json
"""
import numpy as np
import torch

from amfe.training.anypredict import rule_members
from amfe.training.conformal import calibrate
from amfe.training.ensemble import relative_spread
from amfe.vocab import LABEL_NAMES
from run.common import parser, write_json
from run.report.anybed_eval import load_models, read_kind

#: The spans between shipped sizes [mm] (the last runs to the rule's largest side).
SPANS = ((0.6, 1.2), (1.2, 4.0001))


def main():
    p = parser(__doc__)
    p.add_argument("--sets", nargs="+", required=True)
    p.add_argument("-o", "--output", required=True)
    args = p.parse_args()
    torch.set_num_threads(1)
    models = load_models(None)
    means, spreads, labels, sizes = [], [], [], []
    for path in args.sets:
        fill, bonds, y, (_, _, _, box), _ = read_kind(path)
        members = rule_members(models["shipped"], fill, bonds, box[0], box[1])
        means.append(members.mean(axis=0))
        spreads.append(relative_spread(members))
        labels.append(y)
        sizes.append({"set": path.rsplit("/", 1)[-1], "side_mm": float(box[0]), "n": len(y)})
    spans = []
    for lo, hi in SPANS:
        rows = [k for k, sz in enumerate(sizes) if lo <= sz["side_mm"] < hi]
        if not rows:
            continue
        cal = calibrate(np.concatenate([means[k] for k in rows]),
                        np.concatenate([labels[k] for k in rows]), list(LABEL_NAMES),
                        np.concatenate([spreads[k] for k in rows]))
        spans.append({"lo_mm": lo, "hi_mm": hi, "sets": [sizes[k] for k in rows],
                      "calibration": cal})
        print(f"{lo:g}-{hi:g} mm: {cal['n']} beds, quantiles "
              + ", ".join(f"{k} {v:.3g}" for k, v in cal["quantile"].items()))
    write_json(args.output, {"format": "amfe.sizerule_calibration", "format_version": 2,
                             "coverage": 0.9, "spans": spans})
    print(f"wrote {args.output}")

if __name__ == "__main__":
    main()

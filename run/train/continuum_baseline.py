"""Does the continuum springs' model beat the paper springs' model times a factor (issue 47)?

On continuum-spring test beds: the paper springs' small model as is, the same times its
median ratio to the labels per constant (fitted on the calibration beds), and the
continuum model; mean relative error % per constant, the continuum model's flag
(share flagged, recall of beds more than 10 % off), and the spread of the label /
paper-prediction ratio over the test beds (docs/surrogate.md, "The continuum springs'
model").

    .venv/bin/python -m run.train.continuum_baseline TEST.h5 CALIBRATION.h5
"""
import numpy as np

from run.common import parser


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("test", help="continuum-spring test beds (seed 47200)")
    ap.add_argument("calibration", help="continuum-spring calibration beds (seed 47300)")
    ap.add_argument("--paper", default="amfe/models/multiscale_small.pt")
    ap.add_argument("--continuum", default="amfe/models/multiscale_small_continuum.pt")
    args = ap.parse_args(argv)
    import torch

    from amfe.training.data import read_rows
    from amfe.training.predict import Surrogate
    from amfe.vocab import LABEL_NAMES
    torch.set_num_threads(1)
    paper, cont = Surrogate.load(args.paper), Surrogate.load(args.continuum)
    x_cal, y_cal = read_rows(args.calibration, None, paper.inputs)
    factor = np.median(y_cal / paper.predict(x_cal)["mean"], axis=0)
    x, y = read_rows(args.test, None, paper.inputs)
    p, c = paper.predict(x)["mean"], cont.predict(x)["mean"]

    def mre(pred):
        return " | ".join(f"{v:.2f}" for v in 100 * np.mean(np.abs(pred / y - 1), axis=0))
    print(f"{len(y)} test beds; factor (median label / paper prediction on {len(y_cal)} "
          f"calibration beds): {np.round(factor, 4)}")
    print("| model | " + " | ".join(LABEL_NAMES) + " |\n|---|" + "---|" * 6)
    print(f"| the paper springs' model, as is | {mre(p)} |")
    print(f"| the same, times the factor | {mre(p * factor)} |")
    print(f"| the continuum springs' model | {mre(c)} |")
    ratio = y / p
    print("label / paper prediction, 5-95 % of the beds: " + ", ".join(
        f"{n} {np.percentile(ratio[:, k], 5):.3f}-{np.percentile(ratio[:, k], 95):.3f}"
        for k, n in enumerate(LABEL_NAMES)))
    # the continuum model's flag as amfe predict raises it (no risk model: the interval's
    # width over the limit, or the fill check)
    from amfe.training.conformal import interval_block
    res = cont.predict(x)
    size = tuple(float(v) for v in cont.ckpt["pixelation"]["bed_size"])
    flag = np.array([interval_block(res["mean"][k], LABEL_NAMES, cont.ckpt["conformal"], size,
                                    res["spread"][k])["interval_flag"] or bool(res["flagged"][k])
                     for k in range(len(y))])
    bad = np.any(np.abs(c / y - 1) > 0.1, axis=1)
    print(f"continuum model's flag: {flag.mean():.1%} of the beds flagged; {bad.mean():.1%} "
          f"have a constant more than 10 % off, {bad[flag].sum() / max(bad.sum(), 1):.0%} of "
          f"them flagged; bad and unflagged {(bad & ~flag).mean():.1%}")
    med, med_p = np.median(y, axis=0), np.median(p, axis=0)
    print(f"median Ex {med[0] / 1e9:.1f} GPa (paper model {med_p[0] / 1e9:.1f}), nu_xy "
          f"{med[5]:.3f} (paper model {med_p[5]:.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

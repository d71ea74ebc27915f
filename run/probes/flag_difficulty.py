"""Issue 46, the flag: how well can a bed's risk of a constant more than 10 % off be ranked?

For data sets rebuilt from label tables (``amfe dataset --from-labels``), the shipped small
model's predictions, then per bed: image features (fill and bond images: densities, empty
cells, weakest cross-sections, connected pieces of the fill and whether the largest spans the
bed) and the ensemble's spread; a logistic model of "any constant more than 10 % off" fitted
on the calibration seeds, scored on the test seed: the recall of the bad beds and the share
left bad and unflagged at 20, 25, 30 and 35 % flagged.

    python run/probes/flag_difficulty.py --calibration s9.h5 s8.h5 s16.h5 --test s4.h5

Measured (2026-12-05, shipped multiscale_small.pt; calibration seeds 9, 8, 16, 4 500 beds;
test seed 4, 1 000 beds, 11.1 % bad), flagging the calibration's riskiest 20 / 25 / 30 /
35 %: 18.7 / 22.7 / 28.1 / 33.1 % of the test beds flagged, recall 0.77 / 0.83 / 0.86 /
0.89, bad and unflagged 2.5 / 1.9 / 1.5 / 1.2 % of all beds. The ensemble's spread alone
(the shipped interval flag's signal) gives a recall of 0.67 at 20 %. Bad beds are 21.5 %
of the beds with skipped pieces and 1.5 % of the others, mostly on nu_xy.
"""

import numpy as np

from amfe.training.data import dataset_info, read_rows
from amfe.training.flagrisk import fill_pieces
from amfe.training.predict import Surrogate
from run.common import parser


def predictions(sur, path):
    """(features (n, F), prediction (n, 6), labels (n, 6)) of a data set's ok rows."""
    import h5py
    rows = dataset_info(path, sur.inputs)["ok"]
    images, labels = read_rows(path, rows, sur.inputs)
    res = sur.predict(images)
    with h5py.File(path) as f:
        fill = f["images"][()][rows].astype(float)
        bond = f["bond_images"][()][rows].astype(float)
    return features(fill, bond, res), res["mean"], labels


def features(fill, bond, res):
    n = len(fill)
    F = [fill.mean((1, 2, 3))] + [fill[:, k].mean((1, 2)) for k in range(fill.shape[1])]
    F += [(fill < t).mean((1, 2, 3)) for t in (0.05, 0.3, 0.6)]
    bn = bond / (bond.mean() + 1e-30)
    F += [bn.mean((1, 2, 3)), (bn < 1e-3).mean((1, 2, 3))]
    for axis in (2, 3):   # the weakest cross-section along x and y, relative to the mean
        s = bn.sum(axis)
        F.append(s.min(2).min(1) / (s.mean((1, 2)) + 1e-12))
    for thr in (0.15, 0.35):
        pieces = [fill_pieces(fill[i], thr) for i in range(n)]
        F += [np.array(v, dtype=float) for v in zip(*pieces)]
    F += [np.log(res["spread"][:, k] + 1e-6) for k in range(6)]
    F += [res["mean"][:, k] for k in range(3, 6)] + [np.log(res["mean"][:, k]) for k in range(3)]
    return np.stack(F, 1)


def fit_logistic(A, bad, lam=0.1, steps=50):
    w = np.zeros(A.shape[1])
    for _ in range(steps):   # Newton's method on the penalised log-likelihood
        p = 1 / (1 + np.exp(-(A @ w)))
        H = (A * (p * (1 - p))[:, None]).T @ A + lam * np.eye(len(w))
        w -= np.linalg.solve(H, A.T @ (p - bad) + lam * w)
    return w


def main():
    ap = parser(__doc__)
    ap.add_argument("--calibration", nargs="+", required=True)
    ap.add_argument("--test", required=True)
    args = ap.parse_args()
    sur = Surrogate.load()
    parts = [predictions(sur, p) for p in args.calibration]
    X = np.concatenate([p[0] for p in parts])
    P = np.concatenate([p[1] for p in parts])
    Y = np.concatenate([p[2] for p in parts])
    Xt, Pt, Yt = predictions(sur, args.test)
    bad, bad_t = ((np.abs(P - Y) / np.abs(Y) > 0.1).any(1),
                  (np.abs(Pt - Yt) / np.abs(Yt) > 0.1).any(1))
    mu, sd = X.mean(0), X.std(0) + 1e-12

    def design(Z):
        Z = (Z - mu) / sd
        return np.concatenate([np.ones((len(Z), 1)), Z, Z**2], 1)
    w = fit_logistic(design(X), bad)
    score, score_t = design(X) @ w, design(Xt) @ w
    print(f"test: {len(Yt)} beds, {bad_t.mean():.1%} with a constant more than 10 % off")
    for frac in (0.20, 0.25, 0.30, 0.35):
        flag = score_t > np.quantile(score, 1 - frac)
        print(f"  {frac:.0%} flagged on calibration: {flag.mean():.1%} flagged, recall "
              f"{bad_t[flag].sum() / bad_t.sum():.2f}, bad and unflagged {(bad_t & ~flag).mean():.1%}")


if __name__ == "__main__":
    main()

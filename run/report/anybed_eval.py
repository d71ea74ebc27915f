"""Errors of the any-bed surrogate on held-out data sets (issue 46): each constant's mean
relative error, the share of beds with a constant more than 10 % off, and the route.

    python -m run.report.anybed_eval --anybed amfe/models/anybed_small.pt --sets A.h5 B.h5 \
        [--json out.json]
"""
import h5py
import numpy as np
import torch
from scipy.stats import binom

from amfe.training.anypredict import any_members, load_stack_for, route_conformal
from amfe.training.anystack import load_stack
from amfe.training.conformal import interval_block
from amfe.training.ensemble import relative_spread
from amfe.training.predict import Surrogate
from amfe.training.sizerule import SIZES
from amfe.training.thicknets import load_thick
from amfe.vocab import LABEL_NAMES
from run.common import ROOT, md_table, parser, write_json


def load_models(anybed_path, stack_path=None):
    """The shipped models, anybed, the installed networks of one thickness and the stack
    (None: the installed one; "none": without)."""
    shipped = {s: Surrogate.load(f"{ROOT}/amfe/models/multiscale_{name}.pt")
               for s, name in zip(SIZES, ("small", "medium", "paper"))}
    anybed = Surrogate.load(anybed_path) if anybed_path else None
    thick = load_thick() if anybed is not None else {}
    stack = None
    if anybed is not None and stack_path != "none":
        stack = (load_stack_for(anybed, thick) if stack_path is None
                 else load_stack(stack_path, anybed.ckpt.get("created")))
    return {"shipped": shipped, "anybed": anybed, "thick": thick, "stack": stack}


def read_kind(path):
    """(fill, bonds, labels, kind, ok) of a data set of one kind of bed."""
    with h5py.File(path, "r") as f:
        ok = f["status"][:] == 0
        fill, bonds = f["images"][:][ok], f["bond_images"][:][ok]
        labels = f["labels"][:][ok]
        p = f["params"]
        n = int(ok.sum())
        nu = p["nu"][:][ok] if "nu" in p else np.full(n, 0.28)
        psi = p["psi"][:][ok] if "psi" in p else np.full(n, 0.08)
        E = p["E"][:][ok] if "E" in p else np.full(n, 210e9)
        # the imaged box (whole cells, amfe.training.anysize); older sets: the bed's size
        box = np.asarray(f.attrs.get("image_box", f.attrs["bed_size"]), float) * 1e3
    return fill, bonds, labels, (nu, psi, E, box), ok


def predict_set(models, path):
    """(mean predictions (n, 6), labels (n, 6), route, covered (n, 6) bool: the label inside
    the 90 % interval amfe predict gives, flagged (n,) bool: its interval flag, a half-width
    over its limit) of a data set, bed by bed kind."""
    fill, bonds, labels, (nu, psi, E, box), _ = read_kind(path)
    box_m = np.asarray(box, float) * 1e-3
    preds, routes = np.empty_like(labels), set()
    covered = np.zeros(labels.shape, bool)
    flagged = np.zeros(len(labels), bool)
    # beds of one material share one call (a drawn-material set: every bed its own)
    keys = np.stack([nu, psi, E], axis=1)
    for key in np.unique(keys, axis=0):
        rows = np.flatnonzero(np.all(keys == key, axis=1))
        kind = dict(layers=fill.shape[1], lx_mm=box[0], ly_mm=box[1], nu=key[0], psi=key[1],
                    E=key[2])
        members, route = any_members(models, fill[rows], bonds[rows], kind)
        preds[rows] = members.mean(axis=0)
        spread = relative_spread(members)
        for i, row in enumerate(rows):   # the intervals and flag amfe predict gives
            block = interval_block(preds[row], LABEL_NAMES,
                                   route_conformal(models, route, kind, spread[i], box_m),
                                   box_m, spread[i])
            lo, hi = np.array([block["intervals"][k] for k in LABEL_NAMES]).T
            covered[row] = (lo <= labels[row]) & (labels[row] <= hi)
            flagged[row] = block["interval_flag"]
        routes.add(route)
    return preds, labels, ", ".join(sorted(routes)), covered, flagged


def errors(preds, labels, covered, flagged):
    rel = np.abs(preds - labels) / np.abs(labels)
    n = len(labels)
    bad = rel.max(axis=1) > 0.10
    lo, hi = (v / n for v in binom.interval(0.99, n, 0.9))
    cov = covered.mean(axis=0)
    return {"mre": dict(zip(LABEL_NAMES, map(float, rel.mean(axis=0)))),
            "over_10": float(np.mean(bad)), "n": int(n),
            "interval_flagged": float(flagged.mean()),
            "bad_unflagged": float(np.mean(bad & ~flagged)),
            "coverage": dict(zip(LABEL_NAMES, map(float, cov))), "band": [lo, hi],
            "coverage_in_band": bool(np.all((cov >= lo) & (cov <= hi)))}


def main():
    p = parser(__doc__)
    p.add_argument("--anybed", default=None, help="the anybed checkpoint")
    p.add_argument("--stack", default=None,
                   help="the anybed stack (default: the installed one; none: without)")
    p.add_argument("--sets", nargs="+", required=True)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    torch.set_num_threads(1)
    models = load_models(args.anybed, args.stack)
    rows, out = [], {}
    for path in args.sets:
        preds, labels, route, covered, flagged = predict_set(models, path)
        e = errors(preds, labels, covered, flagged)
        out[path] = {**e, "route": route}
        rows.append([path.rsplit("/", 1)[-1], e["n"], route]
                    + [f"{100 * e['mre'][k]:.2f}" for k in LABEL_NAMES]
                    + [f"{100 * e['over_10']:.1f}", f"{100 * e['interval_flagged']:.1f}",
                       f"{100 * e['bad_unflagged']:.1f}",
                       f"{100 * min(e['coverage'].values()):.1f}-"
                       f"{100 * max(e['coverage'].values()):.1f}"
                       + ("" if e["coverage_in_band"] else " (out of band)")])
    print(md_table(["set", "beds", "route", *LABEL_NAMES, "> 10 % off (%)", "flagged (%)",
                    "> 10 % off, unflagged (%)", "90 % coverage (%)"], rows))
    if args.json:
        write_json(args.json, out)


if __name__ == "__main__":
    main()

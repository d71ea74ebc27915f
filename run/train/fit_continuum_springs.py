"""Fit the continuum springs (amfe.model.continuum_springs) to issue 47's voxel labels.

Reads every committed continuum table (labels/continuum/voxel_ladders_*.h5), rebuilds each
labelled bed from its plan (run/report/continuum_ladders.py ``bed_of``), and chooses alpha,
beta_n, beta_t that minimise the mean squared log ratio of the frame's six moduli (Ex, Ey,
Ez, G_yz, G_xz, G_xy, KUBC, as the labels) to the extrapolated continuum ones, over the
beds not held out whose solid fraction lies in FIT_RANGE (0.2-0.8, issue 47's range), each
label weighted by its extrapolation error (Nelder-Mead in the parameters' logs). Then it
prints, for the held-out beds (every fifth bed of the plan, never used here) and the
fitting beds, each constant's error with
the paper's springs and with the fitted ones, by solid fraction, and writes the parameter
file (amfe/models/springs_continuum.json by default) with the fit's data and residuals.

    python -m run.train.fit_continuum_springs [--tables labels/continuum] [-o FILE]
    python -m run.train.fit_continuum_springs --check    # the shipped fit on unseen beds
    python -m run.train.fit_continuum_springs --bound    # what a per-bed scale could reach
"""
import glob
import json
import math
import os
import time

import h5py
import numpy as np
from scipy.optimize import minimize

from amfe.api import homogenize
from amfe.errors import AmfeError
from amfe.model.continuum_springs import (
    PARAMS_FILE,
    SPRINGS_FORMAT,
    ContinuumSprings,
    load_params,
    neck_share,
)
from amfe.model.frame import build_frame
from run.common import ROOT, md_table, parser, write_json
from run.report.continuum_ladders import bed_of

MODULI = ("Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy")
NUS = ("nu_yz", "nu_xz", "nu_xy")
BINS = ((0.0, 0.2), (0.2, 0.35), (0.35, 0.5), (0.5, 0.6), (0.6, 1.0))
#: The solid fractions the springs are fitted on (issue 47's range); sparser beds of the plan
#: (a few dozen particles in a tiny box) are evaluated, not fitted.
FIT_RANGE = (0.2, 0.8)
#: A label's weight is 1 / (FLOOR^2 + its relative GCI error^2): a label the ladder could not
#: extrapolate well counts less.
FLOOR = 0.03


def read_labels(folder):
    """[{index, seed, held_out, solid_fraction, moduli (6,), moduli_error (6,), nus (3,)}]:
    every labelled bed (status 0) of the tables in ``folder``."""
    beds = []
    for path in sorted(glob.glob(os.path.join(folder, "voxel_ladders_*.h5"))):
        with h5py.File(path, "r") as f:
            names = [str(n) for n in f.attrs["extrapolated_names"]]
            props = [str(n) for n in f.attrs["property_names"]]
            order = [names.index(n) for n in MODULI]
            for r in np.flatnonzero(f["status"][:] == 0):
                beds.append({
                    "table": os.path.basename(path),
                    "index": int(f["index"][r]), "seed": int(f.attrs["plan_seed"]),
                    "held_out": bool(f["held_out"][r]),
                    "n_particles": int(f["n_particles"][r]),
                    "solid_fraction": float(f["solid_fraction"][r, -1]),
                    "moduli": f["extrapolated_value"][r][order],
                    "moduli_error": f["extrapolated_error"][r][order],
                    # the Poisson ratios of the finest rung (no extrapolation)
                    "nus": f["properties"][r, -1][[props.index(n) for n in NUS]]})
    return beds


def frame_constants(bed, springs):
    """(moduli (6,), nus (3,)) of ``bed`` under KUBC with ``springs``."""
    res = homogenize(bed, springs=springs)
    return (np.array([res.properties[n] for n in MODULI]),
            np.array([res.properties[n] for n in NUS]))


def rebuilt(rec):
    """The Bed of label ``rec``, rebuilt from its plan (its particle count checked)."""
    bed = bed_of(rec["seed"], rec["index"])[0]
    if bed.n != rec["n_particles"]:
        raise AmfeError(f"bed {rec['index']} of plan {rec['seed']} rebuilt with {bed.n} "
                        f"particles, the table says {rec['n_particles']}")
    return bed


def check(beds, made):
    """Print the shipped springs' errors (and the paper's) on the beds their fit never used."""
    params = load_params()
    with open(PARAMS_FILE) as f:
        used = set(json.load(f)["fit"]["tables"])
    unseen = [k for k, b in enumerate(beds) if b["held_out"] or b["table"] not in used]
    picked = [beds[k] for k in unseen], [made[k] for k in unseen]
    rows = []
    for name, springs in (("paper", "paper"), ("continuum", params)):
        logs, dnu = evaluate(*picked, springs)
        rows += summary_rows(f"unseen, {name}", picked[0], logs, dnu)
    print(f"{len(unseen)} beds the fit of {params.version} never used "
          f"({sum(b['table'] not in used for b in beds)} in tables packed after it)")
    print(md_table(["beds, springs", "solid fraction", "n", *MODULI, *NUS], rows))


def scalar_bound():
    """Print, per part of the shipped fit (held out, fit), each modulus' share of beds within
    10 % as fitted and after removing each bed's mean log ratio of the six: the best any
    correction that scales a bed's moduli alike could do; what is left is the frame's
    anisotropy against the continuum's."""
    with open(PARAMS_FILE) as f:
        residuals = json.load(f)["fit"]["residuals"]
    for part, res in residuals.items():
        logs = np.array(res["log_ratio"])
        for how, x in (("as fitted", logs), ("each bed's level removed",
                                             logs - logs.mean(axis=1, keepdims=True))):
            within = (np.abs(np.expm1(x)) <= 0.1).mean(axis=0)
            print(f"{part} ({len(logs)} beds), {how}: within 10 % "
                  + ", ".join(f"{n} {w:.0%}" for n, w in zip(MODULI, within))
                  + f"; mean log ratio {np.round(x.mean(axis=0), 3)}")


def bed_neck_share(bed):
    """The mean neck share of ``bed``'s load-carrying particles under KUBC."""
    frame = build_frame(bed.centers, bed.radii, bed.material(), size=bed.attrs.get("size"))
    b = frame.bonds
    return float(neck_share(b.i, b.j, b.a, frame.radii).mean())


def evaluate(beds, made, springs):
    """(log ratios (n, 6) of frame / continuum moduli, nu differences (n, 3))."""
    logs, dnu = [], []
    for rec, bed in zip(beds, made):
        m, nu = frame_constants(bed, springs)
        logs.append(np.log(m / rec["moduli"]))
        dnu.append(nu - rec["nus"])
    return np.array(logs), np.array(dnu)


def summary_rows(name, beds, logs, dnu):
    """Table rows: per solid-fraction bin and all, each constant's mean |relative error| %,
    the share within 10 % (moduli), the mean |nu difference| and the share within 0.03."""
    phi = np.array([b["solid_fraction"] for b in beds])
    rows = []
    for lo, hi in BINS + ((0.0, 1.0),):
        sel = (phi >= lo) & (phi < hi)
        if not sel.any():
            continue
        rel = np.abs(np.expm1(logs[sel])) * 100
        cells = [f"{rel[:, k].mean():.1f} ({(rel[:, k] <= 10).mean():.0%})"
                 for k in range(6)]
        cells += [f"{np.abs(dnu[sel, k]).mean():.3f} ({(np.abs(dnu[sel, k]) <= 0.03).mean():.0%})"
                  for k in range(3)]
        where = "all" if (lo, hi) == (0.0, 1.0) else f"{lo:.2f}-{hi:.2f}"
        rows.append([name, where, str(int(sel.sum()))] + cells)
    return rows


def main():
    ap = parser(__doc__)
    ap.add_argument("--tables", default=os.path.join(ROOT, "labels", "continuum"))
    ap.add_argument("-o", "--output", default=str(PARAMS_FILE))
    ap.add_argument("--version", default=time.strftime("%Y-%m-%d"))
    ap.add_argument("--check", action="store_true",
                    help="fit nothing: the shipped springs on every bed their fit never used "
                         "(held out, or in a table packed after it)")
    ap.add_argument("--bound", action="store_true",
                    help="fit nothing: from the shipped fit's stored residuals, the share of "
                         "beds within 10 %% if each bed's six moduli were also scaled alike "
                         "by the best factor for that bed")
    args = ap.parse_args()
    if args.bound:
        return scalar_bound()
    beds = read_labels(args.tables)
    if not beds:
        raise SystemExit(f"no labelled beds in {args.tables}")
    made = [rebuilt(rec) for rec in beds]
    if args.check:
        return check(beds, made)
    fit = [k for k, b in enumerate(beds) if not b["held_out"]
           and FIT_RANGE[0] <= b["solid_fraction"] <= FIT_RANGE[1]]
    held = [k for k, b in enumerate(beds) if b["held_out"]]
    pick = lambda ks: ([beds[k] for k in ks], [made[k] for k in ks])  # noqa: E731

    weight = np.array([1.0 / (FLOOR**2 + (beds[k]["moduli_error"] / beds[k]["moduli"])**2)
                       for k in fit])
    weight /= weight.mean()

    def loss(log_beta):
        springs = ContinuumSprings(*np.exp(log_beta))
        logs, _ = evaluate(*pick(fit), springs)
        return float(np.mean(weight * logs**2))

    t0 = time.perf_counter()
    best = minimize(loss, x0=np.log([0.15, 0.31, 5.6]), method="Nelder-Mead",
                    options={"xatol": 1e-3, "fatol": 1e-7, "maxfev": 200})
    beta = np.exp(best.x)
    phis = [bed_neck_share(made[k]) for k in fit]
    fitted = ContinuumSprings(*beta, version=args.version, phi_range=(min(phis), max(phis)))
    print(f"fit on {len(fit)} beds in {time.perf_counter() - t0:.0f} s "
          f"({best.nfev} evaluations): beta_n = {beta[0]:.5g}, beta_t = {beta[1]:.5g}, "
          f"alpha = {beta[2]:.5g}, "
          f"weighted rms log ratio {math.sqrt(best.fun):.4f}")
    rows, residuals = [], {}
    for part, ks in (("held out", held), ("fit", fit)):
        for name, springs in (("paper", "paper"), ("continuum", fitted)):
            logs, dnu = evaluate(*pick(ks), springs)
            rows += summary_rows(f"{part}, {name}", pick(ks)[0], logs, dnu)
            if name == "continuum":
                print(f"{part}: mean log ratio {np.round(logs.mean(axis=0), 3)}, mean nu "
                      f"difference {np.round(dnu.mean(axis=0), 3)}")
                residuals[part] = {"index": [beds[k]["index"] for k in ks],
                                   "log_ratio": logs.round(5).tolist(),
                                   "nu_difference": dnu.round(5).tolist()}
    print(md_table(["beds, springs", "solid fraction", "n", *MODULI, *NUS], rows))
    write_json(args.output, {
        "format": SPRINGS_FORMAT, "version": args.version,
        "model": "1/k = 1/k_paper + beta (c_i + c_j), c_p = phi_p / (E R_p^m); "
                 "beta_n: k_n, kappa_t; beta_t: k_t, kappa_n (docs/model.md, section 11)",
        "alpha": float(beta[2]), "beta_n": float(beta[0]), "beta_t": float(beta[1]),
        "phi_range": [float(v) for v in fitted.phi_range],
        "fit": {"tables": sorted(os.path.basename(p) for p in
                                 glob.glob(os.path.join(args.tables, "voxel_ladders_*.h5"))),
                "plan_seed": beds[0]["seed"], "beds_fit": len(fit), "beds_held_out": len(held),
                "solid_fraction_range": list(FIT_RANGE),
                "loss": "weighted mean squared log ratio of the six moduli, KUBC; weight "
                        f"1 / ({FLOOR}^2 + relative GCI error^2)",
                "weighted_rms_log_ratio": math.sqrt(best.fun), "evaluations": int(best.nfev),
                "residuals": residuals}})
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()

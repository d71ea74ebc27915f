"""Issue 47's independent check of the continuum labels: a finer voxel model on held-out beds.

For each given bed of the plan (held out of the springs' fit), solves the voxel model at
H = R/PER_RADIUS (default R/8, finer than the ladder's R/3-R/5) through the matrix-free
operator, KUBC on the bed's box as the ladder, and prints its six moduli against the
label (the ladder's extrapolation with its GCI error), the ladder's finest rung, and the
frame with the paper's and the continuum springs.

    python -m run.report.continuum_check --beds 74 84 94 [--per-radius 8] [--ranks 1]
"""
import glob
import os
import tempfile

import h5py
import numpy as np

from amfe.api import homogenize
from amfe.io.bedfile import write_bed
from run.common import ROOT, md_table, parser
from run.report.continuum_ladders import bed_of
from run.report.voxel_ladder import run_one

MODULI = ("Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy")


def label_of(index, folder):
    """{seed, value (6,), error (6,), finest (6,), solid_fraction} of bed ``index``."""
    for path in glob.glob(os.path.join(folder, "voxel_ladders_*.h5")):
        with h5py.File(path, "r") as f:
            rows = np.flatnonzero(f["index"][:] == index)
            if rows.size and f["status"][rows[0]] == 0:
                r = rows[0]
                names = [str(n) for n in f.attrs["extrapolated_names"]]
                props = [str(n) for n in f.attrs["property_names"]]
                order = [names.index(n) for n in MODULI]
                return {"seed": int(f.attrs["plan_seed"]), "held_out": bool(f["held_out"][r]),
                        "value": f["extrapolated_value"][r][order],
                        "error": f["extrapolated_error"][r][order],
                        "finest": f["properties"][r, -1][[props.index(n) for n in MODULI]],
                        "solid_fraction": float(f["solid_fraction"][r, -1])}
    raise SystemExit(f"bed {index} has no label in {folder}")


def main():
    ap = parser(__doc__)
    ap.add_argument("--beds", type=int, nargs="+", required=True)
    ap.add_argument("--per-radius", type=float, default=8.0)
    ap.add_argument("--ranks", type=int, default=1)
    ap.add_argument("--tables", default=os.path.join(ROOT, "labels", "continuum"))
    args = ap.parse_args()
    rows = []
    for index in args.beds:
        label = label_of(index, args.tables)
        bed = bed_of(label["seed"], index)[0]
        h = float(bed.radii.mean()) / args.per_radius
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "bed.h5")
            write_bed(path, bed)
            res, seconds, rss = run_one(path, "kubc", args.ranks,
                                        ["--model", "voxel", "--voxel-size", repr(h),
                                         "--voxel-operator", "matrix-free"])
        fine = np.array([res["properties"][n] for n in MODULI])
        frames = {s: np.array([homogenize(bed, springs=s).properties[n] for n in MODULI])
                  for s in ("paper", "continuum")}
        for k, name in enumerate(MODULI):
            v, e = label["value"][k], label["error"][k]
            rows.append([str(index), f"{label['solid_fraction']:.2f}", name,
                         f"{v / 1e9:.1f} +- {e / 1e9:.1f}", f"{label['finest'][k] / 1e9:.1f}",
                         f"{fine[k] / 1e9:.1f}", f"{fine[k] / v - 1:+.1%}",
                         "yes" if abs(fine[k] - v) <= e else "no",
                         f"{frames['paper'][k] / v - 1:+.1%}",
                         f"{frames['continuum'][k] / v - 1:+.1%}"])
        print(f"bed {index}: R/{args.per_radius:g} in {seconds:.0f} s, "
              f"{rss / 2**30:.2f} GiB", flush=True)
    print(md_table(["bed", "solid fraction", "modulus", "label [GPa] (GCI)", "R/5 [GPa]",
                    f"R/{args.per_radius:g} [GPa]", f"R/{args.per_radius:g} / label",
                    "within GCI", "paper frame / label", "continuum frame / label"], rows))


if __name__ == "__main__":
    main()

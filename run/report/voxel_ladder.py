"""A bed's voxel model on a ladder of voxel sizes, extrapolated to H -> 0, beside the frame.

docs/model.md, section 10 ("Convergence in H", "The model-error table").
Each level is one `amfe homogenize BED --model voxel --voxel-size H` process
(H = mean radius / level), timed, with its peak resident set size from
wait4 (the largest process of the run: mpirun reports its ranks'). Each
constant is extrapolated by :func:`amfe.model.extrapolate.extrapolate`
(generalised Richardson, GCI error), and least-squares fits at orders 1 and
2 are stored beside it. ``--frame`` also runs the paper's frame on the same
bed and condition and stores the ratio frame / extrapolated continuum.

    .venv/bin/python -m run.report.voxel_ladder BED.h5 --bc periodic --levels 4 6 8 \
        --ranks 2 --frame -o ladder.json [--centres-box] [--voxel-operator matrix-free]
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

from amfe.io.bedfile import read_bed
from amfe.model.extrapolate import extrapolate, fit_order

KEYS = ["Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy"]
from run.common import ROOT, parser  # noqa: E402


def run_one(bed, bc, ranks, extra):
    """(result dict, wall seconds, peak RSS bytes) of one `amfe homogenize` process."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "r.json")
        cmd = [sys.executable, "-m", "amfe", "homogenize", bed, "--bc", bc, "--quiet",
               "-o", out] + extra
        if ranks > 1:
            cmd = ["mpirun", "-n", str(ranks)] + cmd
        t = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - t
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            sys.exit(f"voxel_ladder: {' '.join(cmd)} exited {proc.returncode}")
        with open(out) as fh:
            return json.load(fh), seconds, usage.ru_maxrss * 1024


def centres_box_copy(path, tmp):
    """A copy of the bed at ``path`` whose recorded size is its centres' box, origin at the
    lowest centre: under KUBC every face then cuts its boundary layer of spheres, for both
    models (docs/model.md, section 10, "Non-periodic beds: the box decides the limit")."""
    from amfe.io.bedfile import write_bed
    bed = read_bed(path)
    lo = bed.centers.min(axis=0)
    attrs = dict(bed.attrs) | {"size": (bed.centers.max(axis=0) - lo).tolist()}
    out = os.path.join(tmp, "centres_box.h5")
    write_bed(out, type(bed)(bed.centers - lo, bed.radii, attrs))
    return out


def level_record(level, H, res, seconds, rss):
    m = res["model"]
    return {"per_radius": level, "voxel_size": H, "properties": res["properties"],
            "voxels": m["voxels"], "dofs": m["dofs"], "solid_fraction": m["solid_fraction"],
            "necks_resolved_share": m["necks_resolved_share"],
            "iterations": res["solver"]["iterations"], "seconds": seconds,
            "peak_rss_bytes": rss, "warnings": res["warnings"]}


def extrapolated(levels):
    """{constant: Extrapolation dict + order-1 and order-2 least-squares f0} in Pa."""
    h = np.array([lv["voxel_size"] for lv in levels])
    out = {}
    for k in KEYS:
        f = np.array([lv["properties"][k] for lv in levels])
        rec = extrapolate(h, f).as_dict()
        if len(h) >= 2:
            rec["fit_order_1"] = fit_order(h, f, 1.0)[0]
            rec["fit_order_2"] = fit_order(h, f, 2.0)[0]
        out[k] = rec
    return out


def main():
    ap = parser(__doc__)
    ap.add_argument("bed")
    ap.add_argument("--bc", default="periodic", choices=["periodic", "kubc"])
    ap.add_argument("--levels", type=float, nargs="+", default=[4, 6, 8],
                    help="voxels per mean radius, R/H")
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--frame", action="store_true", help="also run the frame")
    ap.add_argument("--label", default=None)
    ap.add_argument("--max-memory", default=None)
    ap.add_argument("--voxel-operator", default="assembled", choices=["assembled", "matrix-free"])
    ap.add_argument("--centres-box", action="store_true",
                    help="KUBC on the box of the centres (written as the bed's size)")
    ap.add_argument("-o", "--output", required=True)
    args = ap.parse_args()
    args.bed = os.path.abspath(args.bed)   # the runs start in the repository root
    if args.centres_box:
        keep = tempfile.TemporaryDirectory()
        args.bed = centres_box_copy(args.bed, keep.name)
    R = float(np.mean(read_bed(args.bed).radii))
    record = {"bed": args.bed, "label": args.label or os.path.basename(args.bed), "bc": args.bc,
              "mean_radius": R, "ranks": args.ranks,
              "kubc_box": "centres" if args.centres_box else "bed", "machine": platform.node(),
              "voxel_operator": args.voxel_operator,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "levels": []}
    extra_mem = ["--max-memory", args.max_memory] if args.max_memory else []
    for level in args.levels:
        H = R / level
        res, s, rss = run_one(args.bed, args.bc, args.ranks,
                              ["--model", "voxel", "--voxel-size", repr(H),
                               "--voxel-operator", args.voxel_operator] + extra_mem)
        record["levels"].append(level_record(level, H, res, s, rss))
        p = res["properties"]
        print(f"R/{level:g}: {res['model']['dofs']} DOFs, Ex {p['Ex'] / 1e9:.2f} Ey "
              f"{p['Ey'] / 1e9:.2f} Ez {p['Ez'] / 1e9:.2f} G_yz {p['G_yz'] / 1e9:.2f} GPa, "
              f"{s:.1f} s, {rss / 2**30:.2f} GiB", flush=True)
        if len(record["levels"]) >= 2:
            record["extrapolated"] = extrapolated(record["levels"])
        with open(args.output, "w") as fh:   # after every level: a long ladder keeps its rungs
            json.dump(record, fh, indent=1)
    if args.frame:
        res, s, rss = run_one(args.bed, args.bc, args.ranks, [])
        record["frame"] = {"properties": res["properties"], "seconds": s, "peak_rss_bytes": rss,
                           "n_particles": res["n_particles"], "n_removed": res["n_removed"]}
        record["ratio"] = {k: res["properties"][k] / record["extrapolated"][k]["value"]
                           for k in KEYS}
    for k, e in record["extrapolated"].items():
        print(f"{k}: {e['value'] / 1e9:.2f} +- {e['error'] / 1e9:.2f} GPa (order {e['order']:.2f}"
              f"{'; ' + e['note'] if e['note'] else ''})"
              + (f"; frame / continuum {record['ratio'][k]:.2f}" if "ratio" in record else ""))
    with open(args.output, "w") as fh:
        json.dump(record, fh, indent=1)


if __name__ == "__main__":
    main()

"""Pack issue 47's voxel ladders (run/report/continuum_ladders.py, one JSON a bed) into one
committed HDF5 label table, labels/continuum/voxel_ladders_seed<S>_<FIRST>-<END>.h5.

The table holds, for beds FIRST..END-1 of the plan (the consecutive beds whose JSON
exists, from FIRST): the bed's plan record (family, seed, held out or not, particles),
every rung of its H ladder (voxels per radius, voxel size, the nine constants, solid
fraction, share of necks resolved, voxels, DOFs, iterations, seconds), the moduli
extrapolated to H -> 0 with their GCI error, order and note
(run/report/voxel_ladder.py ``extrapolated``), and the paper frame's nine constants on
the same bed and condition. Units: Pa for moduli, m for sizes. A bed whose ladder
failed has status 1 and its reason; its numbers are NaN. docs/datasets.md, "Continuum
labels", describes the columns.

    python -m run.report.continuum_table /work/labels47/beds --seed 47001 -o labels/continuum/
"""
import json
import os
import time

import h5py
import numpy as np

from amfe.io.atomic import atomic_write_h5
from run.common import parser
from run.report.continuum_ladders import BOXES
from run.report.voxel_ladder import KEYS as EXTRAPOLATED

#: The nine constants of every rung and of the frame, in this order.
NAMES = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy")
FORMAT, FORMAT_VERSION = "amfe.continuum_ladders", 1


def consecutive(folder, first=0):
    """[(k, record)] of the beds first, first+1, ... whose JSON exists, up to the first gap."""
    out, k = [], first
    while os.path.exists(path := os.path.join(folder, f"bed_{k:05d}.json")):
        with open(path) as f:
            out.append((k, json.load(f)))
        k += 1
    return out


def columns(records):
    """{name: array} of the table's columns for [(k, record)] (one ladder length for all)."""
    ladders = [r.get("ladder") for _, r in records]
    levels = {tuple(lv["per_radius"] for lv in lad["levels"]) for lad in ladders if lad}
    if len(levels) != 1:
        raise SystemExit(f"error: the beds' ladders differ ({sorted(levels)}): one table each")
    per_radius = np.array(levels.pop(), float)
    n, L = len(records), len(per_radius)

    c = {"index": np.array([k for k, _ in records]), "per_radius": per_radius,
         "status": np.array([0 if lad else 1 for lad in ladders], np.uint8),
         "reason": np.array([" ".join(r.get("error", [])) for _, r in records], object),
         "family": np.array([r["family"] for _, r in records], object),
         "bed_seed": np.array([r["bed_seed"] for _, r in records], np.int64),
         "held_out": np.array([r["held_out"] for _, r in records], bool),
         "n_particles": np.array([r["n_particles"] for _, r in records], np.int64),
         "bed_seconds": np.array([r["seconds"] for _, r in records]),
         "voxel_size": np.full((n, L), np.nan), "properties": np.full((n, L, 9), np.nan),
         "solid_fraction": np.full((n, L), np.nan), "necks_resolved_share": np.full((n, L), np.nan),
         "voxels": np.zeros((n, L, 3), np.int64), "dofs": np.zeros((n, L), np.int64),
         "iterations": np.zeros((n, L, 6), np.int32), "seconds": np.full((n, L), np.nan),
         "frame_properties": np.full((n, 9), np.nan), "frame_seconds": np.full(n, np.nan)}
    for what in ("value", "error", "order"):
        c[f"extrapolated_{what}"] = np.full((n, len(EXTRAPOLATED)), np.nan)
    c["extrapolated_note"] = np.full((n, len(EXTRAPOLATED)), "", object)
    for i, lad in enumerate(ladders):
        if not lad:
            continue
        for j, lv in enumerate(lad["levels"]):
            c["voxel_size"][i, j] = lv["voxel_size"]
            c["properties"][i, j] = [lv["properties"][k] for k in NAMES]
            for key in ("solid_fraction", "necks_resolved_share", "voxels", "dofs",
                        "iterations", "seconds"):
                c[key][i, j] = lv[key]
        for m, k in enumerate(EXTRAPOLATED):
            for what in ("value", "error", "order", "note"):
                c[f"extrapolated_{what}"][i, m] = lad["extrapolated"][k][what]
        c["frame_properties"][i] = [lad["frame"]["properties"][k] for k in NAMES]
        c["frame_seconds"][i] = lad["frame"]["seconds"]
    return c, ladders


def write_table(path, records, seed):
    """The table of [(k, record)] at ``path``, atomically (a kill leaves no half file)."""
    c, ladders = columns(records)
    first = next(lad for lad in ladders if lad)

    def fill(f):
        for name, a in c.items():
            f.create_dataset(name, data=a, dtype=h5py.string_dtype() if a.dtype == object
                             else a.dtype)
        f.attrs.update(format=FORMAT, format_version=FORMAT_VERSION, plan_seed=int(seed),
                       property_names=list(NAMES), extrapolated_names=list(EXTRAPOLATED),
                       boxes=json.dumps(BOXES), bc=first["bc"], kubc_box=first["kubc_box"],
                       ranks=int(first["ranks"]), voxel_operator=first["voxel_operator"],
                       dates=f"{ladders[0]['date'] if ladders[0] else '?'} to "
                             f"{next(lad for lad in ladders[::-1] if lad)['date']}",
                       created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    atomic_write_h5(path, fill)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("folder", help="continuum_ladders' output folder (bed_<k>.json)")
    ap.add_argument("--seed", type=int, default=47001, help="the plan's seed")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("-o", "--output", required=True, help="the folder of the table")
    args = ap.parse_args(argv)
    records = consecutive(args.folder, args.first)
    if not records:
        raise SystemExit(f"error: no bed_{args.first:05d}.json in {args.folder}")
    end = records[-1][0] + 1
    path = os.path.join(args.output,
                        f"voxel_ladders_seed{args.seed}_{args.first:05d}-{end:05d}.h5")
    os.makedirs(args.output, exist_ok=True)
    write_table(path, records, args.seed)
    print(f"wrote {path}: beds {args.first}-{end - 1}, "
          f"{sum('ladder' in r for _, r in records)} with a ladder")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

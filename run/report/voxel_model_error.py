"""The model-error table: the paper's frame against the extrapolated continuum (docs/model.md,
section 10), from stored ladders; and the one line the main job prints from it.

    .venv/bin/python -m run.report.voxel_model_error --ladder fig2=fig2.json per48=per48.json \
        [--rg rg.json] -o docs/voxel_model_error.json      # assemble, print the tables
    .venv/bin/python -m run.report.voxel_model_error --update docs/voxel_model_error.json \
        --ladder fig2grip=new.json -o docs/voxel_model_error.json   # add or replace beds
    .venv/bin/python -m run.report.voxel_model_error --headline   # the main job's line (no solve)

Ladders come from run/report/voxel_ladder.py --frame, Roberts and Garboczi's cells from
run/report/roberts_garboczi.py. Each constant is re-extrapolated here by
:func:`amfe.model.extrapolate.extrapolate`; the ratio's error is the
continuum's relative error (the frame's constants are exact to the solver's
tolerance).
"""
import argparse
import json
import os
import sys

import numpy as np

from amfe.model.extrapolate import extrapolate
from run.common import ROOT, parser

KEYS = ["Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy", "E_mean"]
"""E_mean: the mean of Ex, Ey, Ez, extrapolated as one constant (it averages the grid's
alignment noise of the three axes)."""
STORE = os.path.join(ROOT, "docs", "voxel_model_error.json")
HEADLINE_BED, HEADLINE_KEY = "periodic48", "E_mean"
"""The line's bed: a periodic one, where no boundary choice enters (under KUBC on the bed's
box the continuum's limit H -> 0 loses its grip on faces no sphere reaches; section 10)."""


def with_mean(props):
    """The constants of KEYS from a result's properties (Pa), E_mean added."""
    out = {k: props[k] for k in KEYS if k != "E_mean"}
    return out | {"E_mean": (props["Ex"] + props["Ey"] + props["Ez"]) / 3.0}


def bed_entry(ladder):
    """The stored record of one ladder: levels, extrapolation, frame, ratio (Pa, s, bytes)."""
    lv = [x | {"properties": with_mean(x["properties"])} for x in ladder["levels"]]
    h = [x["voxel_size"] for x in lv]
    ext = {k: extrapolate(h, [x["properties"][k] for x in lv]).as_dict() for k in KEYS}
    frame = ladder["frame"] | {"properties": with_mean(ladder["frame"]["properties"])}
    ratio = {k: {"value": frame["properties"][k] / ext[k]["value"],
                 "error": frame["properties"][k] / ext[k]["value"] * ext[k]["error"]
                 / ext[k]["value"]} for k in KEYS}
    return {"label": ladder["label"], "bc": ladder["bc"], "mean_radius": ladder["mean_radius"],
            "ranks": ladder["ranks"], "machine": ladder["machine"], "date": ladder["date"],
            "n_particles": frame["n_particles"],
            "levels": [{k: x[k] for k in ("per_radius", "voxel_size", "voxels", "dofs",
                                          "solid_fraction", "necks_resolved_share", "seconds",
                                          "peak_rss_bytes")}
                       | {"properties": {k: x["properties"][k] for k in KEYS}} for x in lv],
            "continuum": ext,
            "frame": {"properties": {k: frame["properties"][k] for k in KEYS},
                      "seconds": frame["seconds"], "peak_rss_bytes": frame["peak_rss_bytes"]},
            "ratio": ratio}


def print_tables(store):
    for key, b in store["beds"].items():
        print(f"\n{b['label']} ({b['bc']}, {b['n_particles']} particles; {b['machine']}, "
              f"{b['date']}, {b['ranks']} rank(s))\n")
        print("| H | DOFs | " + " | ".join(KEYS) + " | s | GiB |")
        print("|---|---:|" + "---:|" * (len(KEYS) + 2))
        for x in b["levels"]:
            print(f"| R/{x['per_radius']:g} | {x['dofs']:,} | "
                  + " | ".join(f"{x['properties'][k] / 1e9:.1f}" for k in KEYS)
                  + f" | {x['seconds']:.0f} | {x['peak_rss_bytes'] / 2**30:.2f} |")
        c, f, r = b["continuum"], b["frame"], b["ratio"]
        print("| continuum, H -> 0 | | " + " | ".join(
            f"{c[k]['value'] / 1e9:.1f} +- {c[k]['error'] / 1e9:.1f}" for k in KEYS) + " | | |")
        print("| frame | | " + " | ".join(f"{f['properties'][k] / 1e9:.1f}" for k in KEYS)
              + f" | {f['seconds']:.1f} | {f['peak_rss_bytes'] / 2**30:.2f} |")
        print("| frame / continuum | | " + " | ".join(
            f"{r[k]['value']:.2f} +- {r[k]['error']:.2f}" for k in KEYS) + " | | |")
        print("orders: " + ", ".join(f"{k} {c[k]['order']:.2f}"
                                      + ("*" if c[k]["factor"] > 1.25 else "") for k in KEYS))
    for cell in store.get("roberts_garboczi", {}).get("cells", []):
        e = cell["E_over_Es"]
        print(f"RG porosity {cell['levels'][-1]['porosity']:.3f} (target "
              f"{cell['target_porosity']}), seed {cell['seed']}: "
              + ", ".join(f"R/{x['per_radius']:g} {x['E_over_Es']:.4f}" for x in cell["levels"])
              + f" -> {e['value']:.4f} +- {e['error']:.4f} (order {e['order']:.2f})")


def headline(path=STORE):
    """The main job's line on the model error, from the stored table (no solve)."""
    try:
        with open(path) as fh:
            b = json.load(fh)["beds"][HEADLINE_BED]
    except (OSError, KeyError, ValueError) as exc:
        return f"model error: no stored measurement ({path}: {exc})"
    r = b["ratio"][HEADLINE_KEY]
    c = b["continuum"][HEADLINE_KEY]
    what = "E (the mean of Ex, Ey, Ez)" if HEADLINE_KEY == "E_mean" else HEADLINE_KEY
    return (f"model error: the paper's springs read {r['value']:.1f} +- {r['error']:.1f} x the "
            f"continuum of the same spheres ({what} of {b['label']}, {b['bc']}: frame "
            f"{b['frame']['properties'][HEADLINE_KEY] / 1e9:.0f} GPa, voxel finite elements "
            f"extrapolated to H -> 0 {c['value'] / 1e9:.0f} +- {c['error'] / 1e9:.0f} GPa; "
            f"measured {b['date']}, docs/voxel_model_error.json, docs/model.md section 10)")


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--ladder", nargs="*", default=[], metavar="KEY=JSON")
    ap.add_argument("--rg", default=None, help="run/report/roberts_garboczi.py's JSON")
    ap.add_argument("-o", "--output", default=None)
    ap.add_argument("--headline", action="store_true")
    ap.add_argument("--update", default=None, metavar="STORE.json",
                    help="start from this store: the ladders given add or replace its beds")
    args = ap.parse_args(argv)
    if args.headline:
        print(headline())
        return
    store = {"source": "run/report/voxel_ladder.py --frame and run/report/roberts_garboczi.py, assembled by "
             "run/report/voxel_model_error.py (docs/model.md, section 10)", "beds": {}}
    if args.update:
        with open(args.update) as fh:
            store = json.load(fh)
    for item in args.ladder:
        key, _, path = item.partition("=")
        with open(path) as fh:
            store["beds"][key] = bed_entry(json.load(fh))
    if args.rg:
        with open(args.rg) as fh:
            store["roberts_garboczi"] = json.load(fh)
        for cell in store["roberts_garboczi"]["cells"]:
            lv = cell["levels"]
            cell["E_over_Es"] = extrapolate([1.0 / x["per_radius"] for x in lv],
                                            [x["E_over_Es"] for x in lv]).as_dict()
    print_tables(store)
    if args.output:
        with open(args.output, "w") as fh:
            json.dump(store, fh, indent=1, default=lambda x: float(np.asarray(x)))
    if HEADLINE_BED in store["beds"] and args.output:
        print("\n" + headline(args.output))
    return 0


if __name__ == "__main__":
    sys.exit(main())

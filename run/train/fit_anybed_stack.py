"""Fit the anybed stack (issue 46): thick beds read through their 3-layer windows, and the
anybed route's intervals per thickness (amfe.training.anystack, docs/surrogate.md, "Any bed").

Every bed given must be one the anybed network never saw: ``PATH:START`` takes a data
set's records from START on, ``PATH:A-B,C-D`` those ranges (the records the network
was not trained on). Per thickness, the stack's coefficients are a ridge fit on them and its
intervals are calibrated on cross-fitted predictions (each bed by a fit without it); a
constant whose cross-fitted error the stack does not lower keeps the network's value.
A thickness with a network of its own (amfe.training.thicknets, the installed ones)
reads it as one more column; its beds must be unseen by that network too.

    python -m run.train.fit_anybed_stack --data L5.h5:1000 L6.h5:300 ... \
        [--anybed amfe/models/anybed_small.pt] [-o amfe/models/anybed_stack.json] [--update]

``--update`` refits only the thicknesses of ``--data`` and keeps the other entries of the
stack file ``-o`` (fitted to the same anybed network), with their data records.
"""
import json
import os
import time

import h5py
import numpy as np
import torch

from amfe.model.scales import get_scale
from amfe.training.anybed import E_TRAINED
from amfe.training.anypredict import stack_reads
from amfe.training.anystack import FORMAT, FORMAT_VERSION, STACK_FILE, cross_fitted, fit
from amfe.training.conformal import calibrate
from amfe.training.ensemble import relative_spread
from amfe.training.thicknets import THICK_FILES, created_stamps
from amfe.vocab import LABEL_NAMES
from run.common import ROOT, md_table, parser, record_spec, write_json
from run.report.anybed_eval import load_models, read_kind


def read_unseen(spec):
    """(fill, bonds, labels at 210 GPa, nu, psi) of a data set's solved records in its ranges."""
    path, in_ranges = record_spec(spec)
    fill, bonds, labels, (nu, psi, E, _), ok = read_kind(path)
    keep = in_ranges(np.flatnonzero(ok))
    labels = labels[keep].astype(np.float64)
    labels[:, :3] *= (E_TRAINED / E[keep])[:, None]
    return fill[keep], bonds[keep], labels, nu[keep], psi[keep]


def data_record(spec):
    """{data set, its scale and seed, records} of a ``PATH[:RANGES]`` (the data set is
    rebuilt from the committed label tables: docs/datasets.md, "The tables of issue 46")."""
    path, _ = record_spec(spec)
    ranges = spec.rpartition(":")[2] if ":" in spec else "all"
    with h5py.File(path, "r") as f:
        attrs = {k: f.attrs[k] for k in ("scale", "seed") if k in f.attrs}
    return {"data_set": os.path.basename(path), "records": ranges,
            **{k: v.item() if hasattr(v, "item") else str(v) for k, v in attrs.items()}}


def layers_of(record):
    """The thickness [layers, as the stack's key] of a data record of :func:`data_record`."""
    return str(int(get_scale(record["scale"]).image_shape[0]))


def mre(members, labels):
    """Mean relative error per constant of the members' mean."""
    return np.mean(np.abs(members.mean(axis=0) - labels) / np.abs(labels), axis=0)


def fit_layers(models, sets, args):
    """{layers: entry} of the beds of each thickness in ``sets`` [(fill, bonds, ...)]."""
    layers = {}
    for f, b, y, nu, psi in sets:
        layers.setdefault(f.shape[1], []).append((f, b, y, nu, psi))
    entries = {}
    for n_layers, parts in sorted(layers.items()):
        f, b, y, nu, psi = (np.concatenate(a) for a in zip(*parts))
        reads = stack_reads(models, f, b, nu, psi)
        coefs = fit(reads, y, args.ridge)
        out = cross_fitted(reads, y, args.folds, args.ridge)
        # A constant the stack does not improve on these beds (cross-fitted) keeps the value of
        # the better network: its row picks that network's log column (1: the anybed network,
        # the last: the network of this thickness), which gives it bit for bit.
        alone = {"network": (reads.direct, 1)}
        if n_layers in THICK_FILES:
            alone["own network"] = (reads.extra[-1], coefs.shape[1] - 1)
        errors = {a: mre(members, y) for a, (members, _) in alone.items()}
        stacked = mre(out, y)
        read = []
        for k in range(6):
            best = min(alone, key=lambda a: errors[a][k])
            if errors[best][k] > stacked[k]:
                read.append("stack")
                continue
            members, column = alone[best]
            coefs[k] = 0.0
            coefs[k, column] = 1.0
            out[..., k] = members[..., k]
            read.append(best)
        entries[str(n_layers)] = {
            "n": int(len(y)), "mre_network": dict(zip(LABEL_NAMES, mre(reads.direct, y))),
            "mre_stack_cross_fitted": dict(zip(LABEL_NAMES, mre(out, y))),
            **({"mre_own_network": dict(zip(LABEL_NAMES, mre(alone["own network"][0], y)))}
               if "own network" in alone else {}),
            "read": dict(zip(LABEL_NAMES, read)), "coefs": coefs.tolist(),
            "calibration": calibrate(out.mean(axis=0), y, list(LABEL_NAMES),
                                     relative_spread(out))}
    return entries


def main():
    p = parser(__doc__)
    p.add_argument("--data", nargs="+", required=True,
                   help="PATH[:START or A-B,C-D] of unseen beds")
    p.add_argument("--anybed", default=os.path.join(ROOT, "amfe", "models", "anybed_small.pt"))
    p.add_argument("-o", "--output", default=os.path.join(ROOT, "amfe", "models", STACK_FILE))
    p.add_argument("--ridge", type=float, default=1e-4)
    p.add_argument("--folds", type=int, default=5)
    p.add_argument("--update", action="store_true",
                   help="keep the other thicknesses' entries of the stack file -o")
    args = p.parse_args()
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    models = load_models(args.anybed, "none")   # the shipped models beside it (3 layers)
    anybed = models["anybed"]
    entries = fit_layers(models, [read_unseen(s) for s in args.data], args)
    data = [data_record(s) for s in args.data]
    if args.update:   # read as it is: the entries refitted may have had other columns
        with open(args.output) as f:
            old = json.load(f)
        if old.get("network_created") != anybed.ckpt.get("created"):
            raise SystemExit(f"error: --update: {args.output} was fitted to another network")
        kept = {n: e for n, e in old["layers"].items() if n not in entries}
        entries = dict(sorted({**kept, **entries}.items(), key=lambda kv: int(kv[0])))
        data = [d for d in old["data"] if layers_of(d) in kept] + data
    rows = []
    for n_layers, e in entries.items():
        for what in ("mre_network", "mre_stack_cross_fitted"):
            rows.append([n_layers, e["n"], what[4:]]
                            + [f"{100 * e[what][k]:.2f}" for k in LABEL_NAMES])
    print(md_table(["layers", "beds", "predictor", *LABEL_NAMES], rows))
    write_json(args.output, {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "network": os.path.relpath(args.anybed, ROOT),
        "network_created": anybed.ckpt.get("created"),
        "ridge": args.ridge, "folds": args.folds,
        "data": data, "layers": entries,
        "thick_networks": created_stamps(models["thick"]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "seconds": time.perf_counter() - t0})
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()

"""Out-of-distribution beds for the surrogate's ensemble flag: made, pixelated, labelled.

    python -m run.train.make_ood [-o /work/data/small_ood.h5] [--per-variant 15]

The `small` scale's distribution (amfe.model.scales) with one thing changed per
variant, outside what the training data saw:

- enl_low:   enlargement factors U(1.02, hi), hi ~ U(1.03, 1.05) (training:
             U(1.05, hi), hi in [1.06, 1.14]): thinner sintering necks;
- enl_high:  U(1.10, hi), hi ~ U(1.15, 1.18): fatter necks (the generator
             shrinks radii to keep a* <= 0.98);
- sparse:    scanned fraction 0.2-0.3 (training 0.35-1);
- rot0_45:   layer rotation 0 or 45 degrees (training 67 or 90);
- wide:      tracks 0.2-0.3 mm wide (training 0.05-0.15);
- jitter:    centre jitter +/-0.06 R (training 0.025).

Each bed is the record of ``amfe.dataset.record.make_record`` (the same
generation, image and PETSc homogenisation as `amfe dataset`, one rank),
its data-set seed 100 + variant number. The file has the data-set layout
of amfe.dataset.datafile (images, labels, C, density, index, seed, status, reason,
params/*, bond_images), plus ``variant`` (M,) strings; its root attributes are those of a
`small` data set (so the shipped model accepts its images) and ``variants``.
Finished records are kept in OUTPUT.parts/ and reused when the script is
run again (kill-safe, like amfe dataset). About 1.5 s per bed on one core.
"""
import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np


from amfe.dataset.parts import STATUS_OK, done_indices, read_part, write_part  # noqa: E402
from amfe.vocab import LABEL_NAMES  # noqa: E402
from amfe.model.scales import MM, PARAM_NAMES, SCALES  # noqa: E402
from run.common import parser

BASE = SCALES["small"]
VARIANTS = {
    "enl_low": dict(enlargement_lo=1.02, enlargement_hi=(1.03, 1.05)),
    "enl_high": dict(enlargement_lo=1.10, enlargement_hi=(1.15, 1.18)),
    "sparse": dict(coverage=(0.2, 0.3)),
    "rot0_45": dict(layer_rotations=(0.0, 45.0)),
    "wide": dict(track_width=(0.2 * MM, 0.3 * MM)),
    "jitter": dict(jitter=0.06),
}


def variant_scale(name):
    return dataclasses.replace(BASE, name=f"small-ood-{name}", **VARIANTS[name])


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("-o", "--output", default="/work/data/small_ood.h5")
    ap.add_argument("--per-variant", type=int, default=15)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args(argv)

    from mpi4py import MPI

    from amfe.dataset.record import load_pixelate, make_record
    from amfe.solvers.petsc import init_petsc

    init_petsc([])
    parts = args.output + ".parts"
    os.makedirs(parts, exist_ok=True)
    plan = [(v, j) for v in args.variants for j in range(args.per_variant)]
    with open(os.path.join(parts, "plan.json"), "w") as fh:
        json.dump({"plan": plan, "variants": {v: str(VARIANTS[v]) for v in args.variants}}, fh)
    pixelate = load_pixelate()
    done = set(done_indices(parts, len(plan)))
    t0 = time.perf_counter()
    for k, (v, j) in enumerate(plan):
        if k in done:
            continue
        seed = 100 + list(VARIANTS).index(v)
        rec = make_record(j, seed, variant_scale(v), MPI.COMM_SELF, pixelate=pixelate)
        rec["index"] = k
        write_part(parts, rec)
        status = "ok" if rec["status"] == STATUS_OK else f"failed: {rec['reason'][:70]}"
        print(f"[{k + 1}/{len(plan)}] {v} #{j}: density {rec['density']:.3f}, {status} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    write_file(args.output, parts, plan)
    print(f"wrote {args.output}: {len(plan)} beds")
    return 0


def write_file(output, parts, plan):
    import h5py

    recs = [read_part(os.path.join(parts, f"rec_{k:08d}.npz")) for k in range(len(plan))]
    n = len(recs)
    tmp = output + ".tmp"
    with h5py.File(tmp, "w") as f:
        f["images"] = np.stack([r["image"] for r in recs]).astype(np.float32)
        f["bond_images"] = np.stack([r["bond_image"] for r in recs]).astype(np.float32)
        f["labels"] = np.stack([r["labels"] for r in recs])
        f["C"] = np.stack([r["C"] for r in recs])
        for key, dtype in (("density", np.float64), ("index", np.int64), ("seed", np.int64),
                           ("status", np.uint8), ("n_particles", np.int64),
                           ("n_removed", np.int64), ("n_bonds", np.int64),
                           ("volume", np.float64)):
            f[key] = np.array([r[key] for r in recs], dtype)
        f.create_dataset("reason", data=[r["reason"] for r in recs], dtype=h5py.string_dtype())
        f.create_dataset("variant", data=[v for v, _ in plan], dtype=h5py.string_dtype())
        pg = f.create_group("params")
        for j, name in enumerate(PARAM_NAMES):
            pg[name] = np.array([r["params"][j] for r in recs])
        f["labels"].attrs["columns"] = list(LABEL_NAMES)
        f.attrs.update({
            "format": "amfe.dataset", "scale": "small", "seed": -1, "count": n,
            "label_names": list(LABEL_NAMES), "bed_size": list(BASE.size),
            "layer_thickness": BASE.layer_thickness,
            "image_cell": [BASE.cell[0], BASE.cell[1], BASE.layer_thickness],
            "image_shape": list(BASE.image_shape), "image_spacing": BASE.image_spacing,
            "variants": json.dumps({v: str(VARIANTS[v]) for v in VARIANTS}),
            "description": "out-of-distribution small beds (run/train/make_ood.py); record k's data-set "
                           "seed is 100 + variant number, its record number the k-th of its "
                           "variant",
        })
    os.replace(tmp, output)


if __name__ == "__main__":
    sys.exit(main())

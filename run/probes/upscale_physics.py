"""Physics upscaling with the frame's own tile labels: how far is the coarse solve's physics
from the bed's label, network aside (issue 34, approach b; docs/surrogate.md).

    .venv/bin/python run/probes/upscale_physics.py [--seed 24] [--records 0 1 2 3 4]

Regenerates paper-scale beds of a data-set seed (training seed 24 by default: this measures,
it chooses nothing), cuts each into 5 x 5 windows of 0.6 mm (the particles whose centres lie
in the window), solves every window with the frame under KUBC and under SUBC, puts the
windows' C into the KUBC coarse solve (amfe.training.upscale.kubc_stiffness), and compares
with the bed's own KUBC label (a solve of the whole bed). Prints the relative error of the
six constants per bed, and their mean.
"""
import argparse
import sys

import numpy as np

from amfe.vocab import LABEL_NAMES as SIX
from run.common import parser

TILE = 0.6e-3


def windows(bed, n):
    """The n x n window beds of ``bed`` (rows along y, columns along x), each shifted to the
    origin with its own size."""
    from amfe.model.bed import Bed
    lz = float(bed.attrs["size"][2])
    out = []
    for r in range(n):
        for c in range(n):
            lo = np.array([c * TILE, r * TILE, 0.0])
            inside = np.all((bed.centers[:, :2] >= lo[:2]) & (bed.centers[:, :2] < lo[:2] + TILE),
                            axis=1)
            out.append(Bed(bed.centers[inside] - lo, bed.radii[inside],
                           dict(bed.attrs, size=[TILE, TILE, lz])))
    return out


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--seed", type=int, default=24)
    p.add_argument("--records", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--labels", help="the seed's data set, for the beds' KUBC C (else solved)")
    p.add_argument("--sub", type=int, nargs=3, default=(4, 4, 4))
    args = p.parse_args(argv)
    from amfe.api import homogenize
    from amfe.model.scales import get_scale, record_seed, sample_bed_params
    import h5py
    from amfe.training.stiffness_predict import nine_constants
    from amfe.model.bed import generate_bed
    from amfe.training.upscale import kubc_stiffness
    sc = get_scale("paper")
    n = int(round(sc.size[0] / TILE))
    six = lambda C: nine_constants(C)[:6]   # noqa: E731
    errs = {"KUBC tiles": [], "SUBC tiles": [], "KUBC tile mean": []}
    for k in args.records:
        bed = generate_bed(**sample_bed_params(sc, record_seed(args.seed, k)))
        if args.labels:   # the data set's own record k (its index k), else a solve here
            with h5py.File(args.labels, "r") as fh:
                row = int(np.flatnonzero(fh["index"][:] == k)[0])
                label = six(fh["C"][row])
        else:
            label = six(np.asarray(homogenize(bed, bc="kubc").to_dict()["C"]))
        C = {"kubc": [], "subc": []}
        for w in windows(bed, n):
            for bc in C:
                C[bc].append(np.asarray(homogenize(w, bc=bc).to_dict()["C"]))
        Ck = np.array(C["kubc"]).reshape(n, n, 6, 6)
        Cs = np.array(C["subc"]).reshape(n, n, 6, 6)
        size = (TILE, TILE, float(bed.attrs["size"][2]))
        for key, pred in (("KUBC tiles", kubc_stiffness(Ck, size, args.sub)),
                          ("SUBC tiles", kubc_stiffness(Cs, size, args.sub)),
                          ("KUBC tile mean", Ck.mean(axis=(0, 1)))):
            e = 100 * (six(pred) - label) / np.abs(label)
            errs[key].append(e)
            print(f"record {k} {key:15s}" + "".join(f"{v:+8.2f}" for v in e), flush=True)
    print(f"{'mean |error| %':22s}" + "".join(f"{n:>8s}" for n in SIX))
    for key, e in errs.items():
        print(f"{key:22s}" + "".join(f"{v:8.2f}" for v in np.abs(e).mean(axis=0)))
    print(f"{'mean signed %':22s}")
    for key, e in errs.items():
        print(f"{key:22s}" + "".join(f"{v:+8.2f}" for v in np.mean(e, axis=0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

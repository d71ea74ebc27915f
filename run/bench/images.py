#!/usr/bin/env python
"""Benchmark the pixelation of powder beds (amfe.dataset.images.pixelate) on one core.

    .venv/bin/python -m run.bench.images [--paper] [--seed S] [--repeat R] [--check] [--profile]
    .venv/bin/python -m run.bench.images --large [--seed S] [--repeat R]

Generates HCP beds (amfe.model.bed.generate_bed, fully scanned) and times
amfe.dataset.images.pixelate with the paper's cells (0.03 mm x 0.03 mm x one 0.1 mm
layer) and the default sampling (median radius / 6): the figure-2 bed
(0.25 x 0.25 x 0.1 mm), a 0.6 x 0.6 x 0.2 mm bed and, with --paper, the
paper-scale 3 x 3 x 0.3 mm bed (about 300 000 particles, a 3 x 100 x 100
image). Prints particles, image shape, best of --repeat times, the peak
memory that pixelate allocates (tracemalloc, one extra run) and, with
--check, the largest and rms pixel difference from a 4x finer sampling
(units: fraction of a cell volume). Targets: the 0.6 mm bed well under 1 s,
the paper bed under 20 s, memory well under 2 GB. BLAS/OpenMP threads are
pinned to one before numpy is imported.

--large (issue 34, speed gate: imaging plus network for a 3 mm bed under 1 s
on one core) times the prediction's imaging of a 3 x 3 x 0.3 mm bed of the
`paper` scale (`amfe pack --scale paper --seed S`) on the shipped model's
grid, both images (fill and bonds) by the numpy path (the old code) and by
the compiled kernels (engine "compiled", amfe.dataset.pixelkernel) in the
same run, checks that they are equal bit for bit, then the fill image at the
sampling amfe predict uses for a bed this large (twice the training's spacing:
amfe.training.imagebox.sample_spacing), and times the network on a 3 mm input:
the shipped model if it takes one, else an AnySizeNet (training/anysize.py, 6
layers in) on a random 6 x 100 x 100 tensor. Issue 46's gate (0.2 s) is read
on the imaging as amfe predict runs it, and the total at the training's own
sampling is printed beside it.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

from amfe.model.bed import generate_bed  # noqa: E402
from amfe.dataset.images import SAMPLES_PER_RADIUS, pixelate  # noqa: E402
from run.common import parser

BEDS = [("figure 2", (0.25, 0.25, 0.1), 1.0), ("0.6 mm", (0.6, 0.6, 0.2), 1.0),
        ("paper", (3.0, 3.0, 0.3), 20.0)]


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--paper", action="store_true",
                    help="also the 3 x 3 x 0.3 mm bed (~300 000 particles)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="runs per bed; the best is reported")
    ap.add_argument("--check", action="store_true",
                    help="compare with a 4x finer in-plane sampling (slow for the paper bed)")
    ap.add_argument("--profile", action="store_true", help="print a cProfile of the last bed")
    ap.add_argument("--large", action="store_true",
                    help="only the 3 mm prediction imaging, numpy vs compiled, and the network")
    args = ap.parse_args(argv)
    try:  # one core (Linux only)
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass
    if args.large:
        from run.bench.images_large import large
        return large(args.seed, args.repeat)

    print(f"{'bed':<10}{'size (mm)':>18}{'particles':>11}{'image':>16}{'seconds':>9}"
          f"{'target':>8}{'peak MB':>9}" + (f"{'max err':>9}{'rms err':>9}" if args.check else ""))
    for name, size, target in BEDS:
        if name == "paper" and not args.paper:
            continue
        bed = generate_bed(tuple(s * 1e-3 for s in size), seed=args.seed)
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            img = pixelate(bed)
            best = min(best, time.perf_counter() - t0)
        tracemalloc.start()
        pixelate(bed)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        line = (f"{name:<10}{' x '.join(f'{s:g}' for s in size):>18}{bed.n:>11}"
                f"{' x '.join(str(s) for s in img.shape):>16}{best:>9.3f}"
                f"{'met' if best < target else 'MISSED':>8}{peak:>9.0f}")
        if args.check:
            fine = pixelate(bed, spacing=float(np.median(bed.radii)) / (4 * SAMPLES_PER_RADIUS))
            d = img.astype(float) - fine
            line += f"{np.abs(d).max():>9.5f}{np.sqrt(np.mean(d * d)):>9.5f}"
        print(line, flush=True)

    if args.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile()
        pr.enable()
        pixelate(bed)
        pr.disable()
        pstats.Stats(pr).sort_stats("tottime").print_stats(10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

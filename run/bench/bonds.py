#!/usr/bin/env python
"""Benchmark the bonded-frame set-up of a ~100 000-particle bed on one core.

    .venv/bin/python -m run.bench.bonds [--size LX LY LZ (mm)] [--seed S] [--repeat R] [--profile]

Generates an HCP bed (amfe.model.bed.generate_bed, default 1.75 x 1.75 x 0.3 mm,
about 100 000 particles, fully scanned), then times the three phases that turn
it into element matrices: amfe.model.bonds.find_bonds (KD-tree pairs + contact
geometry), amfe.model.bonds.bond_springs (paper eqs. 1-4) and
amfe.model.element.element_blocks (the 6x6 blocks). Best of --repeat runs per phase.
Target: under 2 s in total on one core. BLAS/OpenMP threads are pinned to one
before numpy is imported.
"""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

from amfe.model.bed import generate_bed  # noqa: E402
from amfe.model.bonds import bond_springs, find_bonds  # noqa: E402
from amfe.model.element import element_blocks  # noqa: E402
from amfe.model.material import STEEL  # noqa: E402
from run.common import parser

TARGET_S = 2.0


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--size", nargs=3, type=float, default=(1.75, 1.75, 0.3), metavar=("LX", "LY", "LZ"),
                    help="bed size in mm (default 1.75 1.75 0.3: about 100 000 particles)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="runs per phase; the best is reported")
    ap.add_argument("--profile", action="store_true", help="also print a cProfile of one run")
    args = ap.parse_args(argv)
    try:  # one core, as the target says (Linux only)
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass

    t0 = time.perf_counter()
    bed = generate_bed(tuple(s * 1e-3 for s in args.size), seed=args.seed)
    t_gen = time.perf_counter() - t0

    best = {"find_bonds": float("inf"), "bond_springs": float("inf"), "element_blocks": float("inf")}
    for _ in range(args.repeat):
        t = time.perf_counter()
        bonds = find_bonds(bed.centers, bed.radii)
        t1 = time.perf_counter()
        k_n, k_t, kappa_n, kappa_t, _capped = bond_springs(bonds, STEEL)
        t2 = time.perf_counter()
        blocks = element_blocks(bonds.normal, bonds.d_i, bonds.d_j, k_n, k_t, kappa_n, kappa_t)
        t3 = time.perf_counter()
        del blocks
        best["find_bonds"] = min(best["find_bonds"], t1 - t)
        best["bond_springs"] = min(best["bond_springs"], t2 - t1)
        best["element_blocks"] = min(best["element_blocks"], t3 - t2)
    total = sum(best.values())

    print(f"bed {args.size[0]:g} x {args.size[1]:g} x {args.size[2]:g} mm, seed {args.seed}: "
          f"{bed.n} particles, {len(bonds)} bonds (generated in {t_gen:.2f} s, "
          f"{bed.attrs['n_shrunk']} radii shrunk)")
    print(f"{'phase':<16}{'seconds':>10}")
    for name, sec in best.items():
        print(f"{name:<16}{sec:>10.3f}")
    print(f"{'total':<16}{total:>10.3f}   (target < {TARGET_S:g} s on one core: "
          f"{'met' if total < TARGET_S else 'MISSED'})")

    if args.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile()
        pr.enable()
        bonds = find_bonds(bed.centers, bed.radii)
        k_n, k_t, kappa_n, kappa_t, _capped = bond_springs(bonds, STEEL)
        element_blocks(bonds.normal, bonds.d_i, bonds.d_j, k_n, k_t, kappa_n, kappa_t)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(15)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

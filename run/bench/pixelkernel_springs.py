#!/usr/bin/env python
"""The bond-image kernel with the springs of amfe.model.springs against its old inline copy.

    .venv/bin/python run/bench/pixelkernel_springs.py [--pairs P] [--calls C] [--beds SPEC ...]

Issue 44, item 2: amfe.dataset._jit.bond_sums_for compiles the spring model's own
function (amfe.model.springs.paper_springs) into the kernel instead of an
inline copy of eq. 1. This script keeps that copy (``old_bond_sums``, the
kernel as it was before) as the baseline and times both on the same inputs
in one process: P alternating pairs (A B, then B A, ...), each sample the
best of C kernel calls, on a few generated beds (SPEC = scale:seed, scales of
amfe.model.scales). It checks that both give the same sums bit for bit and
prints, per bed, the median time of each and the median of the per-pair
ratios new / old with its quartiles. Gate: within 5 % (ratio <= 1.05).
One core (sched_setaffinity).
"""
import argparse
import math
import os
import time

import numpy as np
from numba import njit

from amfe.dataset._jit import bond_sums_for
from amfe.model.pairkernel import bonds
from amfe.dataset.images import DEFAULT_CELL, image_box
from amfe.model.bonds import COINCIDENT
from amfe.model.scales import bed_for
from amfe.model.springs import A_STAR_MARGIN, critical_a_star, paper_coefficients
from run.common import parser

GATE = 1.05


@njit
def old_bond_sums(c, r, bonds, consts, box, image):
    """The kernel before issue 44 (amfe.dataset._jit.bond_sums at b5fb6c1), eq. 1 inline."""
    i, j, L_all = bonds
    E, one_m_nu2, k_br, psi, limit, coincident = consts
    lo, hi, cell, n = box
    for b in range(i.size):
        p, q, L = i[b], j[b], L_all[b]
        Ri, Rj = r[p], r[q]
        if L <= coincident * max(Ri, Rj):
            return False
        d_i = ((L * L + Ri * Ri) - Rj * Rj) / (2.0 * L)
        if d_i <= 0.0 or L - d_i <= 0.0:
            return False
        heron = (((Ri + Rj - L) * (L + Ri - Rj)) * (L - Ri + Rj)) * (Ri + Rj + L)
        a = math.sqrt(max(heron, 0.0)) / (2.0 * L)
        r_eff = Ri * Rj / (Ri + Rj)
        a_star = a / r_eff
        if not a_star < limit:
            return False
        a = a_star * r_eff
        s = a / r_eff
        bracket = k_br * (1.0 + 2.0 * s) - s
        den = math.sqrt(1.0 - s * s) - psi * (s + s * s * bracket)
        k_n = E * a / one_m_nu2 * (1.0 + s * bracket) / den
        flat = 0
        inside = True
        for ax in (2, 1, 0):
            mid = 0.5 * (c[p, ax] + c[q, ax])
            inside = inside and lo[ax] <= mid < hi[ax]
            flat = flat * n[ax] + min(int(math.floor((mid - lo[ax]) / cell[ax])), n[ax] - 1)
        if inside:
            image[flat] += k_n * (L * L)
    return True


def inputs(scale, seed):
    """The kernel's arguments for the bed of ``scale`` and ``seed``, as bondimage prepares them."""
    bed = bed_for(scale, seed)
    c = np.ascontiguousarray(bed.centers, np.float64)
    r = np.ascontiguousarray(bed.radii, np.float64)
    i, j, length = bonds(c, r, 2.0 * COINCIDENT)
    lo, hi = (np.asarray(v, np.float64) for v in image_box(bed))
    cell = np.array([DEFAULT_CELL[0], DEFAULT_CELL[1], bed.attrs["layer_thickness"]])
    n = np.maximum(np.ceil((hi - lo) / cell - 1e-9).astype(np.int64), 1)
    material = bed.material()
    limit = critical_a_star(material.nu, material.psi) - A_STAR_MARGIN
    E, psi, one_m_nu2, k_br, _ = paper_coefficients(material)
    old = (E, one_m_nu2, k_br, psi, limit, COINCIDENT)
    new = (tuple(float(v) for v in paper_coefficients(material)), limit, COINCIDENT)
    return (c, r, (i, j, length)), (lo, hi, cell, n), old, new, r.size, i.size


def best_of(kernel, args, consts, box, out, calls):
    best = math.inf
    for _ in range(calls):
        out[:] = 0.0
        t = time.perf_counter()
        ok = kernel(*args[:2], args[2], consts, box, out)
        best = min(best, time.perf_counter() - t)
    assert ok
    return best


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--beds", nargs="+", default=["small:1", "small:2", "small:3", "medium:1", "medium:2"])
    ap.add_argument("--pairs", type=int, default=101, help="alternating A/B pairs per bed")
    ap.add_argument("--calls", type=int, default=5, help="kernel calls per sample (best kept)")
    args = ap.parse_args(argv)
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass
    new_kernel = bond_sums_for("paper")
    print("| bed | particles | bonds | old kernel | new kernel | new / old: median | quartiles |")
    print("|---|---|---|---|---|---|---|")
    worst = 0.0
    for spec in args.beds:
        scale, seed = spec.split(":")
        kargs, box, old_c, new_c, n_p, n_b = inputs(scale, int(seed))
        a, b = np.zeros(int(np.prod(box[3]))), np.zeros(int(np.prod(box[3])))
        best_of(old_bond_sums, kargs, old_c, box, a, 1)       # compile, and check
        best_of(new_kernel, kargs, new_c, box, b, 1)
        assert np.array_equal(a, b) and a.max() > 0, "the kernels' sums differ"
        t_old, t_new = [], []
        for k in range(args.pairs):
            order = ((t_old, old_bond_sums, old_c), (t_new, new_kernel, new_c))
            for times, kernel, consts in (order if k % 2 == 0 else order[::-1]):
                times.append(best_of(kernel, kargs, consts, box, a, args.calls))
        ratio = np.array(t_new) / np.array(t_old)
        q1, med, q3 = np.percentile(ratio, [25, 50, 75])
        worst = max(worst, med)
        print(f"| {spec} | {n_p} | {n_b} | {np.median(t_old) * 1e6:.0f} us "
              f"| {np.median(t_new) * 1e6:.0f} us | {med:.3f} | {q1:.3f}-{q3:.3f} |")
    print(f"\nsums equal bit for bit on every bed; worst median ratio {worst:.3f} "
          f"({'within' if worst <= GATE else 'OVER'} the {GATE:.2f} gate)")


if __name__ == "__main__":
    main()

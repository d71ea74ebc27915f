"""Convergence of the voxel model in the voxel size H on a sintered pair (docs/model.md, section 10).

Two spheres of radius R whose neck has a* = a / R_eff = 0.8 (a = 0.4 R), the
box cut through their centres in x (x = 0 and x = L) and padded with void in
y and z, so that KUBC holds each sphere's centre section (a disk of radius R)
and nothing else. The padding's width changes with H, so the printed
quantities are the work per unit strain, K_ij = C_ij V / (E R^3), which the
void does not change. Levels n = nx voxels along L, all of one parity
(docs/model.md, section 10: an even nx puts the neck plane on a node plane,
an odd one through voxel centres, and the two converge from far apart).
Extrapolated to H -> 0 from the three finest levels with an error estimate
(:func:`amfe.model.extrapolate.extrapolate`: generalised Richardson and
Roache's GCI; order 1 with safety factor 3 where the values oscillate).

    .venv/bin/python -m run.report.voxel_convergence [--levels 6 12 24 48]
"""
import argparse
import math
import platform
import time

import numpy as np

from amfe.model.extrapolate import extrapolate
from amfe.model.material import Material
from amfe.model.options import SolveOptions
from amfe.model.voxel import VoxelSolid, grid_over, load_carrying, resolved_share, voxelize
from amfe.solvers.petsclib import PETSc
from amfe.solvers.voxel import voxel_stiffness
from run.common import parser

R = 10e-6
A_STAR = 0.8
KEYS = [("K11", 0, 0), ("K22", 1, 1), ("K12", 0, 1), ("K44", 3, 3), ("K66", 5, 5)]


def pair_run(n, material):
    """The pair's voxel model at n voxels along L, solved on its own box.

    Built here from the geometry's parts, not through homogenize_voxel: the
    frame's KUBC rule (docs/model.md, section 5) holds no piece of two
    particles (two centres lie on one line), while the continuum's prescribed
    centre sections do hold the pair.
    """
    a = 0.5 * A_STAR * R                       # R_eff = R / 2
    L = 2.0 * math.sqrt(R * R - a * a)
    h = L / n
    half = (math.ceil(R / h) + 1) * h          # the outer voxel layer is void
    centers = np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0]])
    grid = grid_over(np.array([0.0, -half, -half]), np.array([L, half, half]), h * (1 + 1e-9))
    solid, pieces, voxels = load_carrying(voxelize(centers, np.full(2, R), grid))
    geo = VoxelSolid(grid=grid, solid=solid, kept=np.arange(2), n_bonds=1, n_bonds_input=1,
                     neck_share=resolved_share(np.array([a]), grid),
                     solid_fraction=float(solid.mean()), pieces_removed=pieces,
                     voxels_removed=voxels, warnings=[])
    t = time.perf_counter()
    C, _, mesh = voxel_stiffness(geo, SolveOptions(rtol=1e-10, material=material),
                                 PETSc.COMM_SELF)
    seconds = time.perf_counter() - t
    C = C * grid.volume / (material.E * R**3)
    return {k: C[i, j] for k, i, j in KEYS}, 3 * mesh.n_nodes, seconds, R / h


def main():
    ap = parser(__doc__)
    ap.add_argument("--levels", type=int, nargs="+", default=[6, 12, 24, 48])
    args = ap.parse_args()
    material = Material(E=210e9, nu=0.28)
    rows = []
    print(f"sintered pair, a* = {A_STAR}, nu = {material.nu}; {platform.node()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"{'nx':>4s} {'R/H':>6s} {'DOFs':>8s} " + " ".join(f"{k:>9s}" for k, _, _ in KEYS)
          + f" {'seconds':>8s}")
    for n in args.levels:
        K, dofs, seconds, per_r = pair_run(n, material)
        rows.append(K)
        print(f"{n:4d} {per_r:6.2f} {dofs:8d} "
              + " ".join(f"{K[k]:9.5f}" for k, _, _ in KEYS) + f" {seconds:8.1f}", flush=True)
    h = 1.0 / np.array(args.levels, float)
    for k, _, _ in KEYS:
        e = extrapolate(h, [r[k] for r in rows])
        print(f"{k}: finest {e.finest:.5f}; extrapolated {e.value:.5f} +- {e.error:.5f} "
              f"(order {e.order:.2f}, Fs {e.factor}{'; ' + e.note if e.note else ''})")

if __name__ == "__main__":
    main()

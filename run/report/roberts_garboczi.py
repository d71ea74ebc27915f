"""Roberts and Garboczi's set-up: periodic cells of random overlapping spheres, E/Es against
porosity, extrapolated in resolution (docs/model.md, section 10).

A cube of side T = --cell radii holds a Poisson number of spheres of radius r
at random centres (:func:`amfe.model.overlap.overlapping_spheres`), voxelised
periodically at H = r / level (T / H = cell x level voxels a side), solid
pieces that do not wind round the torus removed, solved under the periodic
condition. E is the mean of Ex, Ey, Ez over the solid's E_s; each level's
E/E_s is extrapolated to H -> 0 (:func:`amfe.model.extrapolate.extrapolate`).
Roberts and Garboczi used r = 1 um, T = 12 um, 48 to 128 voxels a side
(R/H = 4 to 10.7) and nu_s = 0.1 to 0.4.

    mpirun -n 2 .venv/bin/python -m run.report.roberts_garboczi --porosity 0.3 0.5 \
        --levels 4 6 8 --cell 6 -o rg.json [--into docs/voxel_model_error.json]

Each level is solved by all ranks together (the cell is voxelised on every
rank, as ``amfe homogenize --model voxel`` does). ``--voxel-operator
matrix-free`` reaches Roberts and Garboczi's finest grids (M = 96-128) in a
few GiB; ``--extend OLD.json[:KEY]`` adds the new levels to an earlier
record's cells of the same porosity and seed and extrapolates over all.
"""
import argparse
import json
import platform
import time

import numpy as np

from amfe.model.averages import compliance_and_constants
from amfe.model.extrapolate import extrapolate
from amfe.model.material import Material
from amfe.model.options import SolveOptions
from amfe.model.overlap import overlapping_spheres
from amfe.model.voxel import VoxelSolid, grid_over, load_carrying, voxelize
from amfe.solvers.petsclib import PETSc
from amfe.solvers.voxel import voxel_stiffness
from run.common import parser

R = 1e-6


def cell_level(centers, radii, T, level, material, operator="assembled"):
    """One cell at R/H = level: E/E_s (mean of the three axes), porosity, DOFs, seconds."""
    grid = grid_over(np.zeros(3), np.full(3, T), R / level, even=operator == "matrix-free")
    union = voxelize(centers, radii, grid, periodic=True)
    solid, pieces, gone = load_carrying(union, periodic=True)
    geo = VoxelSolid(grid=grid, solid=solid, kept=np.arange(len(radii)), n_bonds=0,
                     n_bonds_input=0, neck_share=1.0, solid_fraction=float(solid.mean()),
                     pieces_removed=pieces, voxels_removed=gone, warnings=[])
    t = time.perf_counter()
    C, sol, mesh = voxel_stiffness(geo, SolveOptions(bc="periodic", material=material),
                                   PETSc.COMM_WORLD, operator=operator)
    _, props = compliance_and_constants(C)
    E = np.array([props[k] for k in ("Ex", "Ey", "Ez")]) / material.E
    return {"per_radius": level, "voxels_a_side": int(grid.n[0]), "E_over_Es": float(E.mean()),
            "E_axes_over_Es": E.tolist(), "porosity": float(1.0 - union.mean()),
            "load_carrying_fraction": float(solid.mean()), "pieces_removed": pieces,
            "dofs": 3 * mesh.n_nodes, "iterations": sol["iterations"],
            "seconds": time.perf_counter() - t, "operator": operator,
            "ranks": PETSc.COMM_WORLD.getSize()}


def earlier_levels(spec):
    """{(target porosity, seed): levels} of an earlier record, ``FILE.json[:KEY]``
    (KEY: the record's key in a store such as docs/voxel_model_error.json)."""
    if not spec:
        return {}
    path, _, key = spec.partition(":")
    with open(path) as fh:
        record = json.load(fh)
    record = record[key] if key else record
    return {(c["target_porosity"], c["seed"]): c["levels"] for c in record["cells"]}


def main():
    ap = parser(__doc__)
    ap.add_argument("--porosity", type=float, nargs="+", default=[0.3, 0.5])
    ap.add_argument("--levels", type=float, nargs="+", default=[4, 6, 8],
                    help="R/H of each level (with --extend, at least two levels in all)")
    ap.add_argument("--cell", type=float, default=6.0, help="cell side in radii")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--nu", type=float, default=0.2, help="the solid's Poisson ratio")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--voxel-operator", default="assembled",
                    choices=["assembled", "matrix-free"])
    ap.add_argument("--extend", default=None, metavar="OLD.json[:KEY]",
                    help="keep this earlier record's levels of each cell and add the new ones")
    ap.add_argument("--into", default=None, metavar="STORE.json[:KEY]",
                    help="also store the record under KEY (default 'roberts_garboczi') in "
                    "this JSON file")
    args = ap.parse_args()
    root = PETSc.COMM_WORLD.getRank() == 0
    old = earlier_levels(args.extend)
    if len(args.levels) < 2 and not old:
        ap.error("extrapolation needs at least two levels (or --extend an earlier record)")
    material = Material(E=1e9, nu=args.nu)
    T = args.cell * R
    record = {"cell_radii": args.cell, "nu_s": args.nu, "machine": platform.node(),
              "extends": args.extend, "voxel_operator": args.voxel_operator,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "cells": []}
    for phi in args.porosity:
        for seed in args.seeds:
            centers, radii = overlapping_spheres(phi, R, T, seed=seed)
            levels = list(old.get((phi, seed), []))
            for level in args.levels:
                levels.append(cell_level(centers, radii, T, level, material,
                                         args.voxel_operator))
                lv = levels[-1]
                if root:
                    print(f"porosity {phi} seed {seed} R/{level:g}: {lv['voxels_a_side']}^3, "
                          f"{lv['dofs']} DOFs, porosity {lv['porosity']:.3f}, E/Es "
                          f"{lv['E_over_Es']:.4f}, {lv['seconds']:.1f} s", flush=True)
            levels.sort(key=lambda lv: lv["per_radius"])
            h = [R / lv["per_radius"] for lv in levels]
            ext = extrapolate(h, [lv["E_over_Es"] for lv in levels]).as_dict()
            record["cells"].append({"target_porosity": phi, "seed": seed,
                                    "n_spheres": int(len(radii)), "levels": levels,
                                    "E_over_Es": ext})
            if not root:
                continue
            print(f"  E/Es -> {ext['value']:.4f} +- {ext['error']:.4f} (order "
                  f"{ext['order']:.2f}{'; ' + ext['note'] if ext['note'] else ''})", flush=True)
            with open(args.output, "w") as fh:
                json.dump(record, fh, indent=1)
    if args.into and root:
        path, _, key = args.into.partition(":")
        try:
            with open(path) as fh:
                store = json.load(fh)
        except FileNotFoundError:
            store = {}
        store[key or "roberts_garboczi"] = record
        with open(path, "w") as fh:
            json.dump(store, fh, indent=1)


if __name__ == "__main__":
    main()

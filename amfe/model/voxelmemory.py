"""The voxel model's memory, estimated from the bed before any grid is built (issue 45, 11).

A paper-size bed at the default voxel size would be refused by the checks of
:func:`amfe.model.voxel.voxel_solid` and :mod:`amfe.solvers.voxel` only after its
grid and mesh were built (36 s and 2.8 GB); :func:`check_estimate` refuses it first,
from the box, the voxel size and the spheres' volume, with the fixes. Pure numpy.
"""
import numpy as np

from amfe.model.memory import _gib, check_memory, default_limit
from amfe.model.voxelgrid import DEFAULT_VOXELS_PER_RADIUS, grid_over, voxel_bytes


def _length3(size):
    """``size`` as three positive finite lengths (3,) [m], or None."""
    try:
        L = np.asarray(size, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return None
    return L if L.shape == (3,) and np.all(np.isfinite(L)) and np.all(L > 0) else None


def voxel_estimate(centers, radii, voxel_size, period=None, size=None, ranks=1, even=False,
                   operator="assembled"):
    """(bytes, nodes, grid, solid fraction): the voxel model's memory, estimated before any
    grid is built (docs/model.md, section 10, "Memory and the largest beds").

    The box is the period box, else the recorded ``size`` (3,) [m], else the spheres'
    bounding box; the solid fraction the spheres' summed volume over the box's (at most 1;
    overlaps make it a little high); the active nodes that fraction of the grid's nodes
    times (1 + 0.75 h / R)^3, R the mean radius, for the nodes on the solid's surface
    (measured: 59 732 nodes where this says 81 600, a tiny bed at R / 4; 19 521 where it
    says 21 500, a 3 x 3 x 3 lattice at R / 5). Sizes as
    :func:`amfe.model.voxel.voxel_solid`'s.
    """
    if period is not None:
        lo, hi = np.zeros(3), np.asarray(period, float)
    elif _length3(size) is not None:
        lo, hi = np.zeros(3), _length3(size)
    else:   # no size, or a junk one (refused later, where the frame's box is made)
        lo, hi = (centers - radii[:, None]).min(axis=0), (centers + radii[:, None]).max(axis=0)
    grid = grid_over(lo, hi, voxel_size, even=even)
    voxels = float(np.prod(grid.n.astype(float)))
    phi = min(1.0, float(np.sum(4.0 / 3.0 * np.pi * radii ** 3)) / grid.volume)
    surface = (1.0 + 0.75 * float(grid.h.max()) / float(radii.mean())) ** 3
    nodes = min(float(np.prod(grid.n + 1.0)), phi * voxels * surface)
    return voxel_bytes(voxels, nodes, ranks, operator), nodes, grid, phi


def check_estimate(centers, radii, voxel_size, max_memory, **where):
    """AmfeError (:func:`amfe.model.memory.check_memory`'s rule and limit) when
    :func:`voxel_estimate` exceeds ``max_memory`` [bytes] (default half the machine's),
    naming the fixes: a coarser voxel size (one that would fit), the matrix-free operator,
    or a smaller window of the bed. ``where``: :func:`voxel_estimate`'s keywords (period,
    size, ranks, even, operator)."""
    estimate, nodes, grid, phi = voxel_estimate(centers, radii, voxel_size, **where)
    limit = default_limit() if max_memory is None else float(max_memory)
    if estimate <= limit:
        return
    h = float(grid.h.max())
    fixes = [f"a coarser --voxel-size (about {1.1 * h * (estimate / limit) ** (1 / 3):.3g} m "
             f"would fit; the default is the mean radius / {DEFAULT_VOXELS_PER_RADIUS})"]
    if where.get("operator", "assembled") == "assembled":
        free = voxel_estimate(centers, radii, voxel_size,
                              **{**where, "even": True, "operator": "matrix-free"})[0]
        fixes.append(f"--voxel-operator matrix-free (about {_gib(free)})")
    fixes.append("a smaller window of the bed")
    check_memory(estimate, max_memory,
                 f"a voxel model of about {nodes:.3g} nodes ({'x'.join(map(str, grid.n))} "
                 f"voxels of {h:.3g} m, solid fraction about {phi:.2f}) on "
                 f"{where.get('ranks', 1)} "
                 "rank(s)",
                 fix="give " + ", ".join(fixes[:-1]) + " or " + fixes[-1])

"""The voxel model's grid and its memory per voxel and node: what the model
(amfe.model.voxel) and its estimate before any grid is built (amfe.model.voxelmemory)
both need (docs/model.md, section 10)."""
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError
from amfe.model.material import real_number


@dataclass(frozen=True)
class Grid:
    """A regular voxel grid: lowest corner lo (3,) [m], counts n (3,) int, sides h (3,) [m]."""

    lo: np.ndarray
    n: np.ndarray
    h: np.ndarray

    @property
    def shape(self):
        """(nz, ny, nx): the shape of a voxel array."""
        return tuple(int(k) for k in self.n[::-1])

    @property
    def volume(self):
        """Volume of the box [m^3]."""
        return float(np.prod(self.n * self.h))


def grid_over(lo, hi, voxel_size, even=False):
    """The grid that fills the box [lo, hi] with voxels no larger than voxel_size [m].

    n_k = ceil(L_k / voxel_size) voxels per axis (at least 1), sides h_k =
    L_k / n_k: the box is covered exactly (KUBC's faces are its faces) and the
    voxels are bricks within a factor (n_k + 1) / n_k of cubes. ``even``: round
    each n_k up to an even count (a periodic grid the matrix-free operator coarsens).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    voxel_size = real_number("the voxel size", voxel_size)
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise AmfeError(f"the voxel size must be a positive length in m, got {voxel_size!r}")
    size = hi - lo
    if not np.all(size > 0):
        raise AmfeError(f"the voxel model needs a box of positive size, got {size.tolist()} m")
    with np.errstate(over="ignore"):
        counts = np.ceil(size / voxel_size * (1.0 - 1e-12))
    if not np.all(counts < MAX_VOXELS_PER_AXIS):
        raise AmfeError(f"a voxel size of {voxel_size:.4g} m divides the box of "
                        f"{' x '.join(f'{x:.4g}' for x in size)} m into {_count(counts)} voxels: "
                        "far more than any machine holds; give a larger --voxel-size (default: "
                        f"the mean radius / {DEFAULT_VOXELS_PER_RADIUS})")
    n = np.maximum(1, counts).astype(np.int64)
    if even:
        n += n % 2
    return Grid(lo=lo, n=n, h=size / n)


MAX_VOXELS_PER_AXIS = 2.0**40
"""More voxels than this along one axis are refused in :func:`grid_over` (no machine holds
even one such row; the counts would overflow int64 in products)."""


def _count(counts):
    """The product of float voxel counts (3,) as text, without overflowing."""
    with np.errstate(over="ignore"):
        total = float(np.prod(counts))
    return f"{total:.3g}" if np.isfinite(total) else "more than 1e308"


DEFAULT_VOXELS_PER_RADIUS = 4
"""Default voxel size: the mean radius over this (docs/model.md, section 10)."""
GRID_BYTES = 32
"""Bytes per voxel of the grid that every rank holds (solid masks, component labels,
node numbers)."""
NODE_BYTES = 16_000
"""Bytes per active node over all ranks: the matrix (about 81 nonzeros a row), its
constrained copy, GAMG's hierarchy, six cases' vectors and the assembly's temporaries
(peak RSS less the interpreter's: 10.0 kB per node on one rank at 18 000 and 45 000
nodes; on two ranks, twice the largest process's peak: 15.1-16.2 kB per node at
0.35-0.59 M nodes, docs/model.md section 10, "Memory and the largest beds")."""


FREE_NODE_BYTES = 5_000
"""The same for the matrix-free operator (:mod:`amfe.solvers.voxelfree`): the elements'
node lists, the coarse grid's assembled matrix and GAMG (an eighth of the nodes), the
vectors (twice the largest process's peak on 2 ranks: 4.4 kB per node at 1.37 M nodes,
4.7 kB at 0.59 M; docs/model.md section 10, "Matrix-free operator")."""


def voxel_bytes(voxels, nodes, ranks=1, operator="assembled"):
    """Estimated peak bytes over ``ranks`` of a voxel model: grids replicated, the rest shared."""
    per_node = NODE_BYTES if operator == "assembled" else FREE_NODE_BYTES
    return GRID_BYTES * voxels * ranks + per_node * nodes

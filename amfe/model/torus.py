"""Geometry on the torus of a periodic bed (docs/model.md, section 9), vectorised numpy.

A periodic bed fills the box [0, Lx) x [0, Ly) x [0, Lz) and repeats itself
with those periods; its file carries the root attribute ``periodic`` =
[Lx, Ly, Lz] [m] (:func:`periodic_box`). Bond b joins particle i and the
image of j shifted by the integer triple s_b, branch vector
l_b = x_j + s_b * L - x_i (elementwise s * L). The shifts are not stored:
they are the minimum image, unique because every side exceeds 4 R_max (any
other image of a bonded pair is farther than L - 2 R_max > 2 R_max >=
R_i + R_j), so they are recomputed identically wherever the bed is read.

amfe's ABAB HCP lattice (:func:`amfe.model.bed.hcp_lattice`: x spacing 2 r0,
rows sqrt(3) r0 apart with odd rows shifted by r0, B layers shifted by
(r0, r0/sqrt(3)), layers 2 r0 sqrt(2/3) apart) repeats after two rows and
two layers: periods P = (2, 2 sqrt(3), 4 sqrt(2/3)) r0. A periodic bed's
box is a whole number of periods per axis (:func:`snap_box`).
"""
import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order
from scipy.spatial import cKDTree

from amfe.errors import AmfeError
from amfe.model.bonds import check_coincident, contact_geometry

NOT_PERIODIC = ("the bed is not periodic (its file has no 'periodic' attribute [Lx, Ly, Lz]); "
                "--bc periodic needs a bed that tiles space: make one with "
                "`amfe pack --periodic` (Python: amfe.generate_bed(..., periodic=True))")


def hcp_periods(r0):
    """Periods (3,) [m] of amfe's ABAB HCP lattice of base radius r0."""
    return np.array([2.0 * r0, 2.0 * math.sqrt(3.0) * r0, 4.0 * r0 * math.sqrt(2.0 / 3.0)])


def snap_box(size, r0, r_max):
    """Snap a requested box (3,) [m] to whole lattice periods.

    Each axis gets the nearest whole number of periods, raised where needed
    so that L > 4 r_max (the minimum-image condition). Returns (L (3,) [m],
    counts (3,) int periods per axis, moved (3,) = L - size [m]).
    """
    P = hcp_periods(r0)
    size = np.asarray(size, dtype=float)
    counts = np.maximum(np.rint(size / P), np.floor(4.0 * r_max / P) + 1).astype(np.int64)
    return counts * P, counts, counts * P - size


def wrap(points, box):
    """Points (..., 3) mapped into [0, L) per axis (a round-off landing on L maps to 0)."""
    box = np.asarray(box, dtype=float)
    x = np.mod(np.asarray(points, dtype=float), box)
    return np.where(x >= box, 0.0, x)


def periodic_hcp_lattice(counts, r0, offset=(0.0, 0.0, 0.0)):
    """(N,3) sites [m] of the HCP lattice on the torus of ``counts`` (3,) periods.

    The sites of the infinite lattice with origin (r0, r0, r0), moved by
    ``offset`` (3,) [m] and wrapped into [0, L); N = 4 cx cy cz. Order: by
    layer, then row, then x (as hcp_lattice), whatever the offset, so every
    site draws the same random numbers.
    """
    cx, cy, cz = (int(c) for c in counts)
    kz, ky, kx = (k.ravel() for k in np.meshgrid(np.arange(2 * cz), np.arange(2 * cy),
                                                 np.arange(cx), indexing="ij"))
    b_layer = kz % 2
    x = r0 + 2.0 * r0 * kx + r0 * (ky % 2) + r0 * b_layer
    y = r0 + math.sqrt(3.0) * r0 * ky + (r0 / math.sqrt(3.0)) * b_layer
    z = r0 + 2.0 * r0 * math.sqrt(2.0 / 3.0) * kz
    pts = np.stack([x, y, z], axis=1) + np.asarray(offset, dtype=float).reshape(3)
    return wrap(pts, np.asarray(counts) * hcp_periods(r0))


def periodic_box(attrs):
    """The box (3,) [m] of a periodic bed from its attrs (or a Bed); AmfeError if not periodic.

    The error names `amfe pack --periodic`, the way to make one.
    """
    attrs = getattr(attrs, "attrs", attrs)
    if attrs is None or "periodic" not in attrs:
        raise AmfeError(NOT_PERIODIC)
    return check_box(attrs["periodic"])


def check_box(box, radii=None):
    """``box`` as (3,) float [m]; AmfeError unless three positive finite lengths,
    each above 4 max(radii) when radii are given (a unique minimum image)."""
    b = np.asarray(box, dtype=float).reshape(-1)
    if b.shape != (3,) or not np.all(np.isfinite(b) & (b > 0)):
        raise AmfeError(f"the periodic box must be three positive lengths [Lx, Ly, Lz] in m, "
                        f"got {box!r}")
    if radii is not None and not np.all(b > 4.0 * float(np.max(radii))):
        raise AmfeError(f"periodic box {b.tolist()} too small: every side must exceed "
                        f"4 R_max = {4.0 * float(np.max(radii)):.6g} so that each bond has "
                        "one nearest image")
    return b


def find_periodic_pairs(centers, radii, box):
    """Bonded pairs on the torus: (i, j, shift), i < j, sorted by (i, j); shift (M,3) int64.

    x_j + shift * L - x_i is the minimum image; the pair is bonded iff its
    length is below R_i + R_j. centers (N,3) in [0, L), radii (N,), box (3,).
    """
    x = np.asarray(centers, dtype=float)
    box = check_box(box, radii)
    check_coincident(x, radii)   # before the KD-tree: a pile of coincident centres is quadratic
    pairs = cKDTree(x, boxsize=box).query_pairs(r=2.0 * float(np.max(radii)),
                                                output_type="ndarray")
    if pairs.size == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, 3), np.int64)
    lo = np.minimum(pairs[:, 0], pairs[:, 1]).astype(np.int64)
    hi = np.maximum(pairs[:, 0], pairs[:, 1]).astype(np.int64)
    shift = -np.rint((x[hi] - x[lo]) / box).astype(np.int64)
    branch = x[hi] + shift * box - x[lo]
    keep = np.einsum("ij,ij->i", branch, branch) < (radii[lo] + radii[hi]) ** 2
    lo, hi, shift = lo[keep], hi[keep], shift[keep]
    order = np.lexsort((hi, lo))
    return lo[order], hi[order], shift[order]


def find_periodic_bonds(centers, radii, box):
    """(:class:`~amfe.model.bonds.Bonds`, shift (M,3) int64) of a periodic bed.

    The contact geometry is :func:`~amfe.model.bonds.contact_geometry`'s own
    arithmetic on the shifted branch vectors, so a bond inside the box gets
    bit for bit the values the non-periodic code gives it.
    """
    centers, radii = np.asarray(centers, float), np.asarray(radii, float)  # checked (a Bed's)
    box = check_box(box, radii)
    i, j, shift = find_periodic_pairs(centers, radii, box)
    return contact_geometry(centers, radii, i, j, offset=shift * box), shift


def spanning_images(n, i, j, shift):
    """Images (n,3) int64 along a BFS spanning tree of the bonds, and the windings (M,3).

    Along a tree bond from parent p to child c the child's image is chosen so
    that x_c + img_c L - (x_p + img_p L) is the bond's branch vector; every
    bond then has the winding w_b = img_i + s_b - img_j (zero on tree bonds).
    The integer span of the w_b says in which directions the cluster wraps
    round the torus. Vectorised by pointer doubling; the graph must be connected.
    """
    g = sp.coo_matrix((np.arange(1, i.size + 1), (i, j)), shape=(n, n)).tocsr()
    order, pred = breadth_first_order(g + g.T, 0, directed=False, return_predecessors=True)
    if order.size != n:
        raise AmfeError("spanning_images: the bond graph is not connected")
    child = order[1:]
    parent = pred[child]
    fwd = np.asarray(g[parent, child]).ravel()        # bond index + 1 when stored (parent, child)
    rev = np.asarray(g[child, parent]).ravel()
    step = np.zeros((n, 3), np.int64)                 # img_child - img_parent
    step[child[fwd > 0]] = shift[fwd[fwd > 0] - 1]
    step[child[fwd == 0]] = -shift[rev[fwd == 0] - 1]
    img, up = step.copy(), np.where(pred < 0, np.arange(n), pred)
    for _ in range(int(math.ceil(math.log2(max(n, 2)))) + 1):
        img, up = img + img[up], up[up]               # the root has step 0 and is its own parent
    img = img - img[0]
    return img, img[i] + shift - img[j]


def winding_rank(winding):
    """Rank (0-3) of the windings (M,3): 3 = the cluster wraps round x, y and z."""
    w = np.unique(np.asarray(winding), axis=0)
    return int(np.linalg.matrix_rank(w.astype(float))) if w.size else 0

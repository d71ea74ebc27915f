"""The voxel model's geometry: the union of a bed's spheres on a regular grid, pure numpy.

docs/model.md, section 10 ("Geometry", "Necks", "Load-carrying voxels"). A
:class:`Grid` covers the box [lo, lo + n h] with n = (nx, ny, nz) voxels of
sides h (3,) [m]; a voxel is solid when its centre lies inside any sphere
(:func:`voxelize`). Voxel (ix, iy, iz) is element ix + nx (iy + ny iz) and the
solid array has shape (nz, ny, nx) (x varies fastest, as the nodes do).
"""
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from amfe.errors import AmfeError
from amfe.model.bonds import contact_geometry, find_pairs
from amfe.model.carrying import (
    component_labels,
    kubc_held,
    periodic_winding,
    removed_report,
    removed_warning,
)
from amfe.model.hex8 import VERTICES
from amfe.model.kubc import boundary_particles
from amfe.model.memory import check_memory
from amfe.model.torus import check_box, find_periodic_pairs, wrap
from amfe.model.volumebox import placed_box
from amfe.model.voxelgrid import (  # noqa: F401 (the grid's names, re-exported)
    DEFAULT_VOXELS_PER_RADIUS,
    FREE_NODE_BYTES,
    GRID_BYTES,
    MAX_VOXELS_PER_AXIS,
    NODE_BYTES,
    Grid,
    grid_over,
    voxel_bytes,
)
from amfe.model.voxelmemory import check_estimate

NECK_WARN_SHARE = 0.5
"""Below this share of necks resolved by at least 2 voxels across, a warning."""
NECK_ERROR_SHARE = 0.2
"""Below this share, an error: most necks are then one voxel wide or missing,
and the voxel solid no longer joins the spheres the frame joins."""
CHUNK_PAIRS = 1 << 21
"""(sphere, voxel) candidate pairs tested at once in :func:`voxelize` (~100 MB)."""


def voxelize(centers, radii, grid, periodic=False):
    """Solid mask (nz, ny, nx) bool: voxel centres inside any sphere.

    centers (N, 3) [m], radii (N,) [m]. Spheres are handled in chunks of
    :data:`CHUNK_PAIRS` candidate voxels (each sphere's bounding cube), so the
    memory stays bounded whatever N. ``periodic``: the grid is the period box
    and voxels wrap round it (else the spheres are clipped to the box).
    """
    return _inside(centers, radii, grid, 0.5, grid.n, periodic)


def grip_nodes(centers, radii, grid):
    """Grid-node mask (nz + 1, ny + 1, nx + 1) bool: nodes inside or on any sphere.

    centers (N, 3) [m], radii (N,) [m]: KUBC's grip, the frame's boundary
    particles (docs/model.md, section 10, "KUBC"); node (ix, iy, iz) lies at
    grid.lo + (ix, iy, iz) h.
    """
    return _inside(centers, radii, grid, 0.0, grid.n + 1, False, strict=False)


def _inside(centers, radii, grid, offset, counts, periodic, strict=True):
    """Mask (counts[::-1]) bool of the lattice points grid.lo + (idx + offset) h, idx <
    counts (3,), inside any sphere (on it too unless ``strict``), in chunks of spheres."""
    centers = np.asarray(centers, float)
    radii = np.asarray(radii, float)
    counts = np.asarray(counts, np.int64)
    mask = np.zeros(tuple(int(k) for k in counts[::-1]), bool)
    if len(radii) == 0:
        return mask
    m = np.ceil(2.0 * float(radii.max()) / grid.h).astype(np.int64) + 2   # cube side in points
    off = np.stack(np.meshgrid(*(np.arange(k) for k in m), indexing="ij"), -1).reshape(-1, 3)
    chunk = max(1, CHUNK_PAIRS // len(off))
    flat = mask.reshape(-1)
    for s in range(0, len(radii), chunk):
        x, r = centers[s:s + chunk], radii[s:s + chunk]
        first = np.floor((x - r[:, None] - grid.lo) / grid.h - offset).astype(np.int64)
        idx = first[:, None, :] + off[None, :, :]                  # (c, M, 3)
        d = grid.lo + (idx + offset) * grid.h - x[:, None, :]
        d2, r2 = np.einsum("cmk,cmk->cm", d, d), (r * r)[:, None]
        inside = d2 < r2 if strict else d2 <= r2
        if periodic:
            idx = np.mod(idx, counts)
        else:
            inside &= np.all((idx >= 0) & (idx < counts), axis=2)
        idx = idx[inside]
        flat[idx[:, 0] + counts[0] * (idx[:, 1] + counts[1] * idx[:, 2])] = True
    return mask


def neck_voxels(neck_radii, grid):
    """Voxels across each neck, 2 a / max(h), for neck radii a (M,) [m]."""
    return 2.0 * np.asarray(neck_radii, float) / float(np.max(grid.h))


def resolved_share(neck_radii, grid, across=2.0):
    """Share of necks at least ``across`` voxels wide (1.0 without necks)."""
    n = neck_voxels(neck_radii, grid)
    return 1.0 if n.size == 0 else float(np.mean(n >= across))


def check_necks(share, voxel_size, warn=NECK_WARN_SHARE, error=NECK_ERROR_SHARE):
    """A warning (str) when share < warn, None when not; AmfeError when share < error."""
    what = (f"only {100 * share:.0f} % of the necks are at least 2 voxels across at voxel "
            f"size {voxel_size:.4g} m")
    if share < error:
        raise AmfeError(f"{what} (fewer than {100 * error:.0f} %): the voxel solid does not "
                        "join the spheres the bonds join; give a smaller --voxel-size")
    if share < warn:
        return (f"{what} (fewer than {100 * warn:.0f} %): the thinnest necks are under-"
                "resolved and the voxel model is too soft there; use a smaller voxel size")
    return None


def load_carrying(solid, periodic=False, grip=None):
    """(kept mask like solid, pieces removed, voxels removed): the solid pieces that carry load.

    Pieces are face-connected (two voxels sharing only an edge or a vertex
    would hinge). Non-periodic (KUBC): a piece carries load when its
    prescribed nodes hold it; the others float and are removed. With ``grip``
    (grid-node mask (nz + 1, ny + 1, nx + 1) bool, :func:`grip_nodes`) those
    are the gripped nodes, and a piece is held when one of its voxels has at
    least 3 gripped vertices (no three vertices of a brick lie on one line);
    without, the box's faces are prescribed and a piece is held when it
    touches them. Periodic: the largest piece on the torus (pieces joined
    across opposite faces are one) is kept, the others removed.
    """
    labels, count = ndimage.label(solid)
    if count == 0:
        raise AmfeError("the voxel model has no solid voxel: the spheres miss every voxel "
                        "centre; give a smaller voxel size")
    if not periodic:
        if grip is None:
            faces = [labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0],
                     labels[:, :, -1]]
        else:
            nz, ny, nx = solid.shape
            held = sum(grip[c[2]:c[2] + nz, c[1]:c[1] + ny, c[0]:c[0] + nx].astype(np.int8)
                       for c in VERTICES) >= 3
            faces = [labels[held]]
        touching = np.zeros(count + 1, bool)
        for f in faces:
            touching[f.ravel()] = True
        touching[0] = False
        keep = touching
    else:
        a, b = [], []
        for axis in range(3):
            lo, hi = np.take(labels, 0, axis).ravel(), np.take(labels, -1, axis).ravel()
            both = (lo > 0) & (hi > 0)
            a.append(lo[both])
            b.append(hi[both])
        a, b = np.concatenate(a), np.concatenate(b)
        graph = coo_matrix((np.ones(a.size), (a, b)), shape=(count + 1, count + 1))
        _, merged = connected_components(graph, directed=False)
        sizes = np.bincount(merged[labels[labels > 0]], minlength=merged.max() + 1)
        keep = merged == np.argmax(sizes)
        keep[0] = False
    kept = keep[labels]
    pieces = int(count - len(np.unique(labels[kept]))) if kept.any() else count
    if not kept.any():
        raise AmfeError("no solid piece of the voxel model touches its prescribed nodes (the "
                        "box's faces, or the boundary particles' spheres): nothing carries load")
    return kept, pieces, int(solid.sum() - kept.sum())


@dataclass
class VoxelSolid:
    """The voxel model of a bed before meshing (docs/model.md, section 10).

    grid: :class:`Grid`; solid: (nz, ny, nx) bool, the load-carrying voxels;
    kept: indices of the particles kept (section 5's load-carrying pieces);
    n_bonds: bonds among them (n_bonds_input: in the whole bed); neck_share:
    share of their necks >= 2 voxels across; solid_fraction: load-carrying
    solid voxels / all voxels; pieces_removed, voxels_removed: the solid
    pieces taken out at the voxel level; warnings: list of str; removed: the
    particle pieces removed (:func:`amfe.model.carrying.removed_report`, or None);
    grip: KUBC's gripped grid nodes ((nz + 1, ny + 1, nx + 1) bool, those inside
    the frame's boundary particles, :func:`grip_nodes`), or None: the box's faces
    (a solid built by hand, e.g. a box cut through a pair's centres);
    grip_particles: indices of the boundary particles (into the bed), or None;
    box_source: where V's box came from (:data:`amfe.model.carrying.BOX_SOURCES`).
    """

    grid: Grid
    solid: np.ndarray
    kept: np.ndarray
    n_bonds: int
    n_bonds_input: int
    neck_share: float
    solid_fraction: float
    pieces_removed: int
    voxels_removed: int
    warnings: list
    removed: dict = None
    grip: np.ndarray = None
    grip_particles: np.ndarray = None
    box_source: str = None


def voxel_solid(centers, radii, voxel_size=None, period=None, size=None, max_memory=None,
                ranks=1, even=False):
    """The :class:`VoxelSolid` of a bed: centers (N, 3) [m], radii (N,) [m] (a Bed's, checked).

    The particles kept are the frame's under the same condition (docs/model.md,
    section 5, :mod:`amfe.model.carrying`): under KUBC every bonded piece its
    prescribed boundary particles hold; on the torus (``period`` (3,) [m]) the
    pieces that wind round it. The box is the frame's
    (:func:`amfe.model.volumebox.placed_box`: the bed's recorded ``size`` (3,)
    [m] or a GivenBox, else the kept spheres' bounding box; the spheres are
    clipped to it), or the period box [0, L). ``voxel_size`` [m]
    defaults to the mean radius / :data:`DEFAULT_VOXELS_PER_RADIUS`.
    ``max_memory`` [bytes] (default: half the machine's): a grid whose estimate
    (:func:`voxel_bytes`) exceeds it is refused before it is allocated. ``even``: a
    period box gets even voxel counts (:func:`grid_over`). The whole model's estimate
    (:func:`amfe.model.voxelmemory.voxel_estimate`; ``even`` is the matrix-free
    operator's) is checked first, before any pair is found or voxel made.
    """

    centers, radii = np.asarray(centers, float), np.asarray(radii, float)
    if voxel_size is None:
        voxel_size = float(radii.mean()) / DEFAULT_VOXELS_PER_RADIUS
    check_estimate(centers, radii, voxel_size, max_memory, period=period, size=size,
                   ranks=ranks, even=even, operator="matrix-free" if even else "assembled")
    shift = None
    if period is not None:
        L = check_box(period, radii)
        centers = wrap(centers, L)
        i, j, shift = find_periodic_pairs(centers, radii, L)
    else:
        i, j = find_pairs(centers, radii)
    if i.size == 0:
        raise AmfeError(f"the bed has no bonds: none of its {len(radii)} particles overlap")
    a = contact_geometry(centers, radii, i, j, None if shift is None else shift * L).a
    labels = component_labels(len(radii), i, j)
    ids = (kubc_held(centers, radii, labels) if period is None
           else periodic_winding(len(radii), i, j, shift, labels))
    keep = np.isin(labels, ids)
    removed = removed_report(centers, radii, labels, ids, len(radii))
    kept = np.flatnonzero(keep)
    note, source = None, "periodic box"
    if period is not None:
        grid = grid_over(np.zeros(3), L, voxel_size, even=even)
    else:
        lo, L, note, source = placed_box(centers, radii, size, kept)
        grid = grid_over(lo, lo + L, voxel_size)
    voxels = float(np.prod(grid.n.astype(float)))
    check_memory(voxel_bytes(voxels, 0, ranks), max_memory,
                 f"a voxel model of {voxels:.3g} voxels ({'x'.join(map(str, grid.n))}) on "
                 f"{ranks} rank(s)")
    warnings = [note] if note else []
    share = resolved_share(a[keep[i]], grid)
    neck = check_necks(share, voxel_size)
    warnings += ([neck] if neck else []) + removed_warning(
        removed, "kubc" if period is None else "periodic")
    solid = voxelize(centers[kept], radii[kept], grid, periodic=period is not None)
    grip = grip_ids = None
    if period is None:   # gripped where the frame is: its boundary particles (section 10)
        grip_ids = kept[boundary_particles(centers[kept], radii[kept])]
        grip = grip_nodes(centers[grip_ids], radii[grip_ids], grid)
    kept_solid, pieces, n_gone = load_carrying(solid, periodic=period is not None, grip=grip)
    if pieces:
        warnings.append(f"{pieces} solid piece(s) of {n_gone} voxels carry no load (no prescribed "
                        "node holds them, or they are not the largest piece) and were removed")
    return VoxelSolid(grid=grid, solid=kept_solid, kept=kept, n_bonds=int(keep[i].sum()),
                      n_bonds_input=int(i.size), neck_share=share,
                      solid_fraction=float(kept_solid.mean()), pieces_removed=pieces,
                      voxels_removed=n_gone, warnings=warnings, removed=removed, grip=grip,
                      grip_particles=grip_ids, box_source=source)

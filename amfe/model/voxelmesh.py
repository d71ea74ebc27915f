"""The voxel model's mesh: active nodes, their numbering and the stiffness rows, pure numpy.

docs/model.md, section 10 ("Mesh"). The solid voxels are trilinear bricks
(:mod:`amfe.model.hex8`) on a uniform grid, so every element has the same
(24, 24) matrix Ke and the stiffness between a node p and its neighbour
p + d (d in {-1, 0, 1}^3) is a sum of constant 3x3 blocks over the solid
elements around p that hold both: the rows are built per node, in chunks,
without per-element triplets (about 27 blocks a node).

Grid nodes (ix, iy, iz) are numbered ix + mx (iy + my iz) (x fastest), with
m = n + 1 nodes per axis, or m = n on the torus of a periodic grid (node n
is node 0). Active nodes (those of a solid voxel) are numbered in that
order, so a contiguous block of them is a slab in z: PETSc's row blocks.
"""
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError
from amfe.model.hex8 import VERTICES

#: (27, 3) neighbour offsets d, sorted by their linear offset (x fastest), so that
#: the columns of a row come out sorted once the numbering is monotone.
OFFSETS = np.array([(dx, dy, dz) for dz in (-1, 0, 1) for dy in (-1, 0, 1)
                    for dx in (-1, 0, 1)], dtype=np.int64)
CHUNK_NODES = 1 << 13
"""Rows built at once in :func:`block_rows` (~16 MB of temporaries: 3x faster than 2^16 rows,
which leave the cache, measured on 45 000 nodes)."""


@dataclass
class VoxelMesh:
    """Active nodes of a solid (nz, ny, nx) on a grid of counts n (3,).

    ``solid`` is bool on a voxel grid; a coarse grid's is the float solid share
    of each coarse voxel (its stiffness factor, :mod:`amfe.model.voxelmg`).

    m (3,): grid nodes per axis (n + 1, or n when periodic); node_id
    (prod m,) int64: active number of each grid node, -1 if inactive;
    grid_index (n_nodes,) int64: the grid node of each active node;
    solid: the (nz, ny, nx) bool elements; periodic: bool.
    """

    n: np.ndarray
    m: np.ndarray
    solid: np.ndarray
    node_id: np.ndarray
    grid_index: np.ndarray
    periodic: bool

    @property
    def n_nodes(self):
        return int(self.grid_index.size)

    @property
    def n_elements(self):
        return int(np.count_nonzero(self.solid))

    def node_ijk(self, ids):
        """(k, 3) int grid indices (ix, iy, iz) of active nodes ``ids``."""
        g = self.grid_index[ids]
        mx, my = int(self.m[0]), int(self.m[1])
        return np.stack([g % mx, (g // mx) % my, g // (mx * my)], axis=1)

    def boundary_nodes(self, grip=None):
        """KUBC's prescribed active nodes, sorted: those of the grid-node mask ``grip``
        ((nz + 1, ny + 1, nx + 1) bool, :func:`amfe.model.voxel.grip_nodes`), or with
        None those on the box's faces."""
        if self.periodic:
            raise AmfeError("a periodic mesh has no boundary")
        if grip is not None:
            return np.flatnonzero(np.asarray(grip, bool).reshape(-1)[self.grid_index])
        ijk = self.node_ijk(np.arange(self.n_nodes))
        return np.flatnonzero(np.any((ijk == 0) | (ijk == self.n), axis=1))


def build_mesh(solid, periodic=False):
    """The :class:`VoxelMesh` of a solid mask (nz, ny, nx) bool."""
    solid = np.asarray(solid, bool)
    n = np.array(solid.shape[::-1], dtype=np.int64)
    if periodic and np.any(n < 3):
        raise AmfeError(f"a periodic voxel grid needs at least 3 voxels per axis, got {n.tolist()}")
    m = n if periodic else n + 1
    active = np.zeros(tuple(m[::-1]), bool)
    for c in VERTICES:  # node p is vertex c of element p - c
        if periodic:
            active |= np.roll(solid, shift=tuple(c[::-1]), axis=(0, 1, 2))
        else:
            active[c[2]:c[2] + n[2], c[1]:c[1] + n[1], c[0]:c[0] + n[0]] |= solid
    flat = active.reshape(-1)
    grid_index = np.flatnonzero(flat)
    node_id = np.full(flat.size, -1, np.int64)
    node_id[grid_index] = np.arange(grid_index.size)
    return VoxelMesh(n=n, m=m, solid=solid, node_id=node_id, grid_index=grid_index,
                     periodic=bool(periodic))


def offset_blocks(Ke):
    """(8, 27, 3, 3): the block Ke[c, c + d] of vertex c and offset d (zero where c + d is
    not a vertex), the contribution of the element p - c to rows p, columns p + d."""
    W = np.zeros((8, 27, 3, 3))
    for c in range(8):
        for k, d in enumerate(OFFSETS):
            v = VERTICES[c] + d
            if np.all((v >= 0) & (v <= 1)):
                b = int(v[0] + 2 * v[1] + 4 * v[2])
                W[c, k] = Ke[3 * c:3 * c + 3, 3 * b:3 * b + 3]
    return W


def _elements_around(mesh, ijk):
    """(k, 8): element p - c is solid (bool), or its weight (a float ``solid``: a coarse
    grid's solid shares, :mod:`amfe.model.voxelmg`), for nodes at grid indices ijk (k, 3)."""
    out = np.zeros((len(ijk), 8), np.asarray(mesh.solid).dtype)
    for c in range(8):
        e = ijk - VERTICES[c]
        if mesh.periodic:
            e = np.mod(e, mesh.n)
            ok = np.ones(len(e), bool)
        else:
            ok = np.all((e >= 0) & (e < mesh.n), axis=1)
        out[ok, c] = mesh.solid[e[ok, 2], e[ok, 1], e[ok, 0]]
    return out


def block_rows(mesh, Ke, r0, r1):
    """Block CSR of the stiffness rows of active nodes [r0, r1).

    Returns indptr (r1 - r0 + 1,), cols (nnzb,) global active node numbers
    (sorted within a row), blocks (nnzb, 3, 3) in Ke's units. A block is
    stored when some solid element holds both nodes.
    """
    W = offset_blocks(Ke).reshape(8, 27 * 9)
    holds = _vertex_pairs()
    counts, cols, blocks = [], [], []
    for s in range(r0, r1, CHUNK_NODES):
        ids = np.arange(s, min(r1, s + CHUNK_NODES))
        ijk = mesh.node_ijk(ids)
        around = _elements_around(mesh, ijk)
        present = ((around != 0).astype(np.int64) @ holds.astype(np.int64)) > 0   # (k, 27)
        vals = (around.astype(float) @ W).reshape(-1, 27, 3, 3)
        nb = ijk[:, None, :] + OFFSETS[None, :, :]
        if mesh.periodic:
            nb = np.mod(nb, mesh.n)
        else:
            present &= np.all((nb >= 0) & (nb <= mesh.n), axis=2)
            nb = np.clip(nb, 0, mesh.n)
        col = mesh.node_id[nb[..., 0] + mesh.m[0] * (nb[..., 1] + mesh.m[1] * nb[..., 2])]
        if mesh.periodic:  # columns sorted per row: the wrap breaks the offsets' order
            order = np.argsort(np.where(present, col, np.iinfo(np.int64).max), axis=1)
            col = np.take_along_axis(col, order, 1)
            present = np.take_along_axis(present, order, 1)
            vals = np.take_along_axis(vals, order[:, :, None, None], 1)
        counts.append(present.sum(axis=1))
        cols.append(col[present])
        blocks.append(vals[present])
    counts = np.concatenate(counts) if counts else np.zeros(0, np.int64)
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    cols = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    blocks = np.concatenate(blocks) if blocks else np.zeros((0, 3, 3))
    return indptr, cols, blocks


def _vertex_pairs():
    """(8, 27) bool: vertex c + d is a vertex of the element (structural presence)."""
    out = np.zeros((8, 27), bool)
    for c in range(8):
        v = VERTICES[c] + OFFSETS
        out[c] = np.all((v >= 0) & (v <= 1), axis=1)
    return out


def element_loads(mesh, Ke, q, r0, r1):
    """(r1 - r0, 3): rows [r0, r1) of sum over solid elements of Ke q, q (24,) the same
    element vector for all (the periodic condition's affine jumps, section 10)."""
    f = (Ke @ q).reshape(8, 3)
    ids = np.arange(r0, r1)
    around = _elements_around(mesh, mesh.node_ijk(ids))
    return around.astype(float) @ f

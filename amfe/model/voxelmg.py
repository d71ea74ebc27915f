"""The voxel model without its assembled matrix: element lists and a coarse grid, pure numpy.

docs/model.md, section 10 ("Matrix-free operator"). The fine level keeps only
the solid elements' eight active node numbers; its product K u is
gather (element displacements) x Ke x scatter, so it needs 8 integers an
element instead of about 27 3x3 blocks a node. The preconditioner works on a
grid twice as coarse: a coarse voxel holds 2 x 2 x 2 fine ones and gets the
stiffness of a solid brick of twice the side scaled by its solid share (the
Voigt estimate of the eight), so thin necks stay connected, only softer; it
is assembled (an eighth of the nodes) and solved by GAMG. Fine and coarse
nodes are tied by trilinear interpolation, renormalised over the active
coarse nodes so that it keeps translations exactly.
"""
import numpy as np
import scipy.sparse as sp

from amfe.errors import AmfeError
from amfe.model.hex8 import VERTICES
from amfe.model.voxelmesh import VoxelMesh, build_mesh


def element_lists(mesh, r0=0, r1=None):
    """The solid elements whose vertex 0 (lowest corner) is one of the active nodes
    [r0, r1): (nodes (n_e, 8) int64 active node numbers, vertex a at offset VERTICES[a];
    weights (n_e,) their stiffness factors: 1 on a voxel grid, the solid share on a
    coarse one).

    Elements come in the grid's order (x fastest), which is the order of their
    vertex 0, so the elements of consecutive node ranges partition them all.
    """
    r1 = mesh.n_nodes if r1 is None else r1
    solid = np.asarray(mesh.solid)
    ez, ey, ex = np.nonzero(solid != 0)
    mx, my = int(mesh.m[0]), int(mesh.m[1])
    lo, hi = np.searchsorted(mesh.node_id[ex + mx * (ey + my * ez)], [r0, r1])
    e = np.stack([ex[lo:hi], ey[lo:hi], ez[lo:hi]], axis=1).astype(np.int64)
    nodes = np.empty((len(e), 8), np.int64)
    for a, c in enumerate(VERTICES):
        v = e + c
        if mesh.periodic:
            v = np.mod(v, mesh.n)
        nodes[:, a] = mesh.node_id[v[:, 0] + mx * (v[:, 1] + my * v[:, 2])]
    if np.any(nodes < 0):
        raise AmfeError("a solid element has an inactive vertex: the mesh is inconsistent")
    return nodes, solid[ez[lo:hi], ey[lo:hi], ex[lo:hi]].astype(float)


def coarse_mesh(mesh):
    """The :class:`VoxelMesh` of the grid twice as coarse: voxel (i, j, k) holds fine voxels
    2i..2i+1 (and so on); its ``solid`` is their solid share (float, a fine voxel past an
    odd count is void). A periodic grid needs even counts (it stays a torus)."""
    solid = np.asarray(mesh.solid, float)
    n = np.array(solid.shape[::-1], np.int64)
    if mesh.periodic and np.any(n % 2):
        raise AmfeError(f"a periodic voxel grid of {n.tolist()} voxels cannot be coarsened "
                        "(it needs even counts): use the assembled operator")
    nc = (n + 1) // 2
    padded = np.zeros(tuple(2 * nc[::-1]))
    padded[:n[2], :n[1], :n[0]] = solid
    share = padded.reshape(nc[2], 2, nc[1], 2, nc[0], 2).mean(axis=(1, 3, 5))
    coarse = build_mesh(share > 0, periodic=mesh.periodic)
    return VoxelMesh(n=coarse.n, m=coarse.m, solid=share, node_id=coarse.node_id,
                     grid_index=coarse.grid_index, periodic=coarse.periodic)


def coarse_grip(grip, coarse):
    """The coarse grid's gripped nodes: the fine grip ((nz+1, ny+1, nx+1) bool) at the even
    nodes, which the coarse nodes sit on (void past the fine box)."""
    grip = np.asarray(grip, bool)
    out = np.zeros(tuple(coarse.m[::-1]), bool)
    even = grip[::2, ::2, ::2]
    out[:even.shape[0], :even.shape[1], :even.shape[2]] = even
    return out


def prolongation(fine, coarse, r0=0, r1=None):
    """Scalar interpolation rows of the fine active nodes [r0, r1) from the coarse active
    nodes: a CSR matrix (r1 - r0, coarse.n_nodes).

    Fine node i sits at coarse coordinate i / 2 on each axis: an even node on a
    coarse node (weight 1), an odd one halfway (1/2 and 1/2); the product over
    the axes gives up to 8 coarse nodes. Weights of inactive coarse nodes are
    dropped and each row rescaled to sum 1 (every fine active node touches a
    solid fine voxel, whose coarse voxel is active, so no row is empty).
    """
    r1 = fine.n_nodes if r1 is None else r1
    ijk = fine.node_ijk(np.arange(r0, r1))
    k = len(ijk)
    lo, odd = ijk // 2, ijk % 2
    rows, cols, vals = [], [], []
    for corner in VERTICES:
        c = lo + corner * odd                          # the upper neighbour only when odd
        w = np.prod(np.where(odd == 1, 0.5, 1.0 - corner), axis=1)   # even: corner 0 only
        if coarse.periodic:
            c = np.mod(c, coarse.n)
        ok = w > 0
        if not coarse.periodic:
            ok &= np.all(c <= coarse.n, axis=1)
        g = c[:, 0] + coarse.m[0] * (c[:, 1] + coarse.m[1] * c[:, 2])
        cid = np.where(ok, coarse.node_id[np.where(ok, g, 0)], -1)
        ok &= cid >= 0
        rows.append(np.flatnonzero(ok)), cols.append(cid[ok]), vals.append(w[ok])
    P = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(k, coarse.n_nodes))
    sums = np.asarray(P.sum(axis=1)).ravel()
    if np.any(sums <= 0):
        raise AmfeError("a fine voxel node has no active coarse node around it")
    P = sp.diags(1.0 / sums) @ P
    P.sort_indices()
    return P.tocsr()

"""Physics upscaling (issue 34, approach b): a network reads the bed's tiles, a coarse
finite-element solve over the tiles gives the bed's stiffness.

A large bed's image (channels, H, W) is cut into whole tiles of ``tile`` x ``tile``
pixels (a 3 mm bed's 100 x 100 into 5 x 5 tiles of 20 x 20, the 0.6 mm beds the small
models know). A stiffness-head model predicts each tile's C (6, 6) [Pa]. The tiles then
become a continuum: a box of trilinear hexahedra (``sub`` elements a tile along x, y, z),
each with its tile's C, under KUBC (u = E x on the whole boundary, as the labels), and
the bed's C is the volume average of the stress for each unit strain. The series and
parallel paths around holes and tracks then come from mechanics, not from pooling.

Caveat, measured in docs/surrogate.md ("Physics upscaling"): the small models' tile
stiffness is a KUBC label, which carries the stiffening of a KUBC boundary on every tile;
inside a KUBC coarse solve that boundary is counted once per tile instead of once per bed.

Conventions: Voigt order xx, yy, zz, yz, xz, xy with engineering shear strains (C44 = G_yz),
as amfe.model.averages. Image rows run along y, columns along x (amfe.dataset.images).
"""
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import splu

# 2 x 2 x 2 Gauss points of the reference cube [-1, 1]^3; each weighs 1.
_G = 1.0 / np.sqrt(3.0)
_NODES = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)])   # (8, 3), x fastest
_SIGNS = 2.0 * _NODES - 1.0
_POINTS = _SIGNS * _G


def strain_matrices(h):
    """B (8 Gauss points, 6, 24) of a trilinear hexahedron with edges h = (hx, hy, hz) [m],
    and the weight times Jacobian of each point [m^3]: strain (Voigt, engineering) = B u_e,
    u_e the 8 nodes' (ux, uy, uz), nodes ordered x fastest, then y, then z."""
    h = np.asarray(h, np.float64)
    f = 1.0 + _POINTS[:, None, :] * _SIGNS[None, :, :]          # (8 points, 8 nodes, 3)
    dN = np.empty((8, 8, 3))
    for a in range(3):
        others = [b for b in range(3) if b != a]
        dN[..., a] = _SIGNS[None, :, a] * f[..., others[0]] * f[..., others[1]] / 8.0 * (2.0 / h[a])
    B = np.zeros((8, 6, 24))
    dx, dy, dz = dN[..., 0], dN[..., 1], dN[..., 2]
    B[:, 0, 0::3], B[:, 1, 1::3], B[:, 2, 2::3] = dx, dy, dz
    B[:, 3, 1::3], B[:, 3, 2::3] = dz, dy                      # gamma_yz
    B[:, 4, 0::3], B[:, 4, 2::3] = dz, dx                      # gamma_xz
    B[:, 5, 0::3], B[:, 5, 1::3] = dy, dx                      # gamma_xy
    return B, float(np.prod(h)) / 8.0


def _unit_strain(k):
    """The displacement gradient (3, 3) of Voigt unit strain k (engineering shear: a unit
    gamma_yz is eps_yz = eps_zy = 1/2)."""
    E = np.zeros((3, 3))
    pairs = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
    i, j = pairs[k]
    if i == j:
        E[i, i] = 1.0
    else:
        E[i, j] = E[j, i] = 0.5
    return E


def kubc_stiffness(C_tiles, tile_size, sub=(2, 2, 1)):
    """The KUBC stiffness (6, 6) [Pa] of a box of tiles, each a homogeneous anisotropic solid.

    C_tiles: (ny, nx, 6, 6) [Pa], tile (r, c) at y in [r ly, (r + 1) ly), x in [c lx, ...),
    as the image's rows and columns; tile_size: (lx, ly, lz) [m] (only ratios matter);
    sub: hexahedra a tile along x, y, z. The box is one tile high. A box of one C returns it
    (the affine field is exact); in general C is symmetric and at most the tiles' mean (Voigt).
    """
    C_tiles = np.asarray(C_tiles, np.float64)
    ny, nx = C_tiles.shape[:2]
    sx, sy, sz = (int(s) for s in sub)
    NX, NY, NZ = nx * sx, ny * sy, sz
    h = np.asarray(tile_size, np.float64) / np.array([sx, sy, sz])
    B, wdet = strain_matrices(h)

    ex, ey, ez = np.meshgrid(np.arange(NX), np.arange(NY), np.arange(NZ), indexing="ij")
    ex, ey, ez = ex.ravel(), ey.ravel(), ez.ravel()
    Ce = C_tiles[ey // sy, ex // sx]                                   # (E, 6, 6)
    node = lambda ix, iy, iz: ix + (NX + 1) * (iy + (NY + 1) * iz)     # noqa: E731
    conn = np.stack([node(ex + i, ey + j, ez + k) for i, j, k in _NODES], axis=1)   # (E, 8)
    dofs = (3 * conn[:, :, None] + np.arange(3)).reshape(len(conn), 24)
    Ke = np.einsum("gai,eab,gbj->eij", B, Ce, B) * wdet
    n_dof = 3 * (NX + 1) * (NY + 1) * (NZ + 1)
    rows = np.repeat(dofs, 24, axis=1).ravel()
    cols = np.tile(dofs, (1, 24)).ravel()
    K = coo_matrix((Ke.ravel(), (rows, cols)), shape=(n_dof, n_dof)).tocsc()

    ix, iy, iz = np.meshgrid(np.arange(NX + 1), np.arange(NY + 1), np.arange(NZ + 1),
                             indexing="ij")
    ix, iy, iz = ix.ravel(), iy.ravel(), iz.ravel()
    order = np.argsort(node(ix, iy, iz))
    x = (np.stack([ix, iy, iz], axis=1) * h)[order]                    # (nodes, 3), by node id
    on_edge = ((ix == 0) | (ix == NX) | (iy == 0) | (iy == NY) | (iz == 0) | (iz == NZ))[order]
    fixed = np.repeat(on_edge, 3)
    free = ~fixed
    U = np.zeros((n_dof, 6))
    for k in range(6):
        U[:, k] = (x @ _unit_strain(k).T).ravel()
    if free.any():
        lu = splu(K[free][:, free].tocsc())
        U[free] = lu.solve(-(K[free][:, fixed] @ U[fixed]))
    # the volume-averaged stress of each case: (1/V) sum_e sum_g C_e B_g u_e w detJ
    strain = np.einsum("gai,eik->egak", B, U[dofs])                   # (E, 8, 6, cases)
    stress = np.einsum("eab,egbk->ak", Ce, strain) * wdet
    return stress / (wdet * 8 * len(Ce))


def tiles_of(images, tile):
    """(n, rows, cols, channels, tile, tile) whole tiles of images (n, channels, H, W); H and W
    must be whole multiples of ``tile``."""
    images = np.asarray(images)
    n, c, H, W = images.shape
    if H % tile or W % tile:
        raise ValueError(f"an image of {H} x {W} pixels is not whole tiles of {tile}")
    t = images.reshape(n, c, H // tile, tile, W // tile, tile)
    return t.transpose(0, 2, 4, 1, 3, 5)


def upscaled_stiffness(sur, images, tile, tile_size, sub=(2, 2, 1)):
    """The beds' C (n, 6, 6) [Pa] from the tiles' C that the stiffness model ``sur``
    (amfe.training.predict.Surrogate with a stiffness head) predicts, and those tiles' C
    (n, rows, cols, 6, 6). images: (n, channels, H, W); tile_size (lx, ly, lz) [m]."""
    t = tiles_of(images, tile)
    n, ny, nx = t.shape[:3]
    flat = np.ascontiguousarray(t.reshape(n * ny * nx, *t.shape[3:]))
    res = sur.predict(flat)
    if "stiffness" not in res:
        raise ValueError("physics upscaling needs a stiffness-head model (amfe train --head "
                         "stiffness)")
    C_tiles = res["stiffness"].reshape(n, ny, nx, 6, 6)
    return np.stack([kubc_stiffness(C, tile_size, sub) for C in C_tiles]), C_tiles

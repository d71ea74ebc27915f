"""The voxel model's element: the trilinear 8-node brick, isotropic linear elasticity.

docs/model.md, section 10 ("Element"). One brick of sides (hx, hy, hz) with
its vertex a at the offset (a & 1, (a >> 1) & 1, (a >> 2) & 1) from its lowest
corner (x varies fastest, the grid's node order). Displacements are ordered
(u_x, u_y, u_z) per vertex, 24 per element. Voigt order xx, yy, zz, yz, xz, xy
with engineering shears, as everywhere in amfe (amfe/vocab.py).
"""
import numpy as np

#: (8, 3) vertex offsets in units of the sides: vertex a = (a & 1, a >> 1 & 1, a >> 2 & 1).
VERTICES = np.array([[a & 1, (a >> 1) & 1, (a >> 2) & 1] for a in range(8)], dtype=np.int64)
GAUSS = np.array([-1.0, 1.0]) / np.sqrt(3.0)
"""2-point Gauss abscissae on [-1, 1] (weights 1): exact for the brick's
stiffness, whose integrand is at most quadratic in each coordinate."""


def isotropic_D(E, nu):
    """(6, 6) isotropic stiffness [units of E] in Voigt order with engineering shears."""
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    mu = E / (2.0 * (1.0 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.arange(3), np.arange(3)] = lam + 2.0 * mu
    D[np.arange(3, 6), np.arange(3, 6)] = mu
    return D


def shape_gradients(xi, h):
    """(8, 3) gradients dN_a/dx at natural coordinates xi (3,) in [-1, 1]^3 of a brick of
    sides h (3,) [length]: N_a = prod_k (1 + s_ak xi_k) / 2 with s_ak = 2 offset - 1."""
    s = 2.0 * VERTICES - 1.0
    f = 0.5 * (1.0 + s * np.asarray(xi, float))          # (8, 3) one-dimensional factors
    g = np.empty((8, 3))
    for k in range(3):
        others = [m for m in range(3) if m != k]
        # d/dxi_k of the k-th factor is s_ak / 2; dxi/dx = 2 / h_k
        g[:, k] = 0.5 * s[:, k] * f[:, others[0]] * f[:, others[1]] * 2.0 / h[k]
    return g


def strain_matrix(xi, h):
    """(6, 24) B with Voigt strain = B u_e at natural coordinates xi (3,), sides h (3,)."""
    g = shape_gradients(xi, h)
    B = np.zeros((6, 24))
    for a in range(8):
        gx, gy, gz = g[a]
        c = 3 * a
        B[0, c], B[1, c + 1], B[2, c + 2] = gx, gy, gz
        B[3, c + 1], B[3, c + 2] = gz, gy   # gamma_yz = du_y/dz + du_z/dy
        B[4, c], B[4, c + 2] = gz, gx       # gamma_xz
        B[5, c], B[5, c + 1] = gy, gx       # gamma_xy
    return B


def element_stiffness(h, E=1.0, nu=0.3):
    """(24, 24) stiffness [units of E x length] of a brick of sides h (3,), by 2x2x2 Gauss.

    K = sum_q B_q^T D B_q det J, det J = hx hy hz / 8, Gauss weights 1. The
    voxel grid is uniform, so one such matrix serves every element.
    """
    h = np.asarray(h, dtype=float)
    D = isotropic_D(E, nu)
    K = np.zeros((24, 24))
    detJ = np.prod(h) / 8.0
    for xi in np.array(np.meshgrid(GAUSS, GAUSS, GAUSS, indexing="ij")).reshape(3, -1).T:
        B = strain_matrix(xi, h)
        K += B.T @ D @ B * detJ
    return 0.5 * (K + K.T)


def mean_strain_matrix(h):
    """(6, 24) B averaged over the brick: B at its centre (each dN_a/dx_k is bilinear in the
    other two coordinates, whose mean over the cube is the value at the centre), so the
    element's mean stress is D B(0) u_e exactly."""
    return strain_matrix(np.zeros(3), np.asarray(h, dtype=float))

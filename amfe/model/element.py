"""The 12-DOF bond element (docs/model.md, section 4), vectorised over bonds.

DOFs per particle: (u_x, u_y, u_z, theta_x, theta_y, theta_z). A bond from i
to j with unit normal e has its contact point at c = x_i + d_i e = x_j - d_j e.
The springs act on

    translational gap  D  = (u_j + theta_j x (c - x_j)) - (u_i + theta_i x (c - x_i))
                          = u_j - u_i + e x (d_i theta_i + d_j theta_j)
    rotational gap     Dr = theta_j - theta_i

with energy 1/2 D.Du.D + 1/2 Dr.Dth.Dr, where Du = k_n e e^T + k_t (I - e e^T)
(normal and shear springs at the contact point) and Dth = kappa_n e e^T +
kappa_t (I - e e^T) (torsion and bending springs). An infinitesimal rigid
motion gives D = omega x (L - d_i - d_j) e = 0 and Dr = 0, so the element has
exactly six zero-energy modes because d_i + d_j = L. With d_i = d_j = d0 the
local matrix is the paper's eq. 5.

Writing S = [e]_x (S w = e x w) and P = I - e e^T, and using S e = 0,
Du S = k_t S and S^T S = P, K = B^T D B gives the 6x6 blocks

    K_ii = [[ Du,          -k_t d_i S               ],
            [ k_t d_i S,    k_t d_i^2 P + Dth        ]]
    K_ij = [[ -Du,         -k_t d_j S               ],
            [ -k_t d_i S,   k_t d_i d_j P - Dth      ]]
    K_jj = [[ Du,           k_t d_j S               ],
            [ -k_t d_j S,   k_t d_j^2 P + Dth        ]]

and K_ji = K_ij^T. They are built directly in global axes: no local frame is
needed, so the result cannot depend on how the axes normal to the bond are
chosen (:func:`local_frames` and :func:`local_element` exist for the check
K = T^T K' T against the paper's blocks).
"""
import numpy as np


def _skew(e):
    """(M,3,3) matrices S with S w = e x w."""
    S = np.zeros(e.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -e[..., 2], e[..., 1]
    S[..., 1, 0], S[..., 1, 2] = e[..., 2], -e[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -e[..., 1], e[..., 0]
    return S


def element_blocks(normal, d_i, d_j, k_n, k_t, kappa_n, kappa_t):
    """The blocks K_ii, K_ij, K_jj, each (M,6,6), of M bonds in global axes.

    normal: (M,3) unit vectors from i to j; d_i, d_j: (M,) lever arms [length];
    k_n, k_t: (M,) [force/length]; kappa_n, kappa_t: (M,) [force*length].
    The element matrix is [[K_ii, K_ij], [K_ij^T, K_jj]].
    """
    e = np.asarray(normal, dtype=float)
    M = e.shape[0]
    c = lambda v: np.asarray(v, dtype=float)[:, None, None]  # noqa: E731
    kn, kt, Kn, Kt, di, dj = (c(v) for v in (k_n, k_t, kappa_n, kappa_t, d_i, d_j))
    E = e[:, :, None] * e[:, None, :]
    P = np.eye(3) - E
    ktS = _skew(e)
    ktS *= kt
    ktP = P * kt
    Du = E * (kn - kt)  # = k_n E + k_t P
    Du += kt * np.eye(3)
    Dth = E * (Kn - Kt)
    Dth += Kt * np.eye(3)

    # Written slice by slice into the outputs: for ~1e6 bonds every (M,3,3)
    # temporary is ~70 MB, and memory traffic is what this function costs.
    Kii = np.empty((M, 6, 6))
    Kij = np.empty((M, 6, 6))
    Kjj = np.empty((M, 6, 6))
    Kii[:, :3, :3] = Du
    np.negative(Du, out=Kij[:, :3, :3])
    Kjj[:, :3, :3] = Du
    np.multiply(ktS, -di, out=Kii[:, :3, 3:])
    np.multiply(ktS, di, out=Kii[:, 3:, :3])
    np.multiply(ktS, -dj, out=Kij[:, :3, 3:])
    np.multiply(ktS, -di, out=Kij[:, 3:, :3])
    np.multiply(ktS, dj, out=Kjj[:, :3, 3:])
    np.multiply(ktS, -dj, out=Kjj[:, 3:, :3])
    np.multiply(ktP, di * di, out=Kii[:, 3:, 3:])
    Kii[:, 3:, 3:] += Dth
    np.multiply(ktP, di * dj, out=Kij[:, 3:, 3:])
    Kij[:, 3:, 3:] -= Dth
    np.multiply(ktP, dj * dj, out=Kjj[:, 3:, 3:])
    Kjj[:, 3:, 3:] += Dth
    return Kii, Kij, Kjj


def element_matrices(normal, d_i, d_j, k_n, k_t, kappa_n, kappa_t):
    """Full (M,12,12) element matrices in global axes (for tests and small frames)."""
    Kii, Kij, Kjj = element_blocks(normal, d_i, d_j, k_n, k_t, kappa_n, kappa_t)
    K = np.empty((Kii.shape[0], 12, 12))
    K[:, :6, :6], K[:, :6, 6:] = Kii, Kij
    K[:, 6:, :6], K[:, 6:, 6:] = np.transpose(Kij, (0, 2, 1)), Kjj
    return K


def local_element(d_i, d_j, k_n, k_t, kappa_n, kappa_t):
    """(M,12,12) element matrices K' in the bond's local frame (x' along the bond)."""
    M = np.size(k_n)
    e = np.zeros((M, 3))
    e[:, 0] = 1.0
    return element_matrices(e, d_i, d_j, k_n, k_t, kappa_n, kappa_t)


def local_frames(normal, reference=None):
    """(M,3,3) right-handed rotations Q whose rows are the local axes (x' = normal).

    ``reference`` (3,) or (M,3) picks the y' axis as the part of it normal to
    the bond; by default the global axis least aligned with the bond.
    """
    e = np.asarray(normal, dtype=float)
    if reference is None:
        reference = np.eye(3)[np.argmin(np.abs(e), axis=1)]
    ref = np.broadcast_to(np.asarray(reference, dtype=float), e.shape)
    y = ref - np.einsum("ij,ij->i", ref, e)[:, None] * e
    y /= np.linalg.norm(y, axis=1)[:, None]
    z = np.cross(e, y)
    return np.stack([e, y, z], axis=1)


def bond_forces(normal, d_i, d_j, k_n, k_t, kappa_n, kappa_t, u_i, u_j):
    """Spring resultants of M bonds under particle DOFs u_i, u_j (M,6).

    Returns (axial (M,), shear (M,), moment (M,)): the normal spring force
    (positive in tension) [force], the magnitude of the shear force at the
    contact point [force], and the magnitude of the torsion+bending couple
    [force*length].
    """
    e = np.asarray(normal, dtype=float)
    gap = u_j[:, :3] - u_i[:, :3] + np.cross(e, d_i[:, None] * u_i[:, 3:] + d_j[:, None] * u_j[:, 3:])
    gn = np.einsum("ij,ij->i", gap, e)
    shear = np.linalg.norm(gap - gn[:, None] * e, axis=1)
    rot = u_j[:, 3:] - u_i[:, 3:]
    rn = np.einsum("ij,ij->i", rot, e)
    rt = rot - rn[:, None] * e
    moment = np.sqrt((kappa_n * rn) ** 2 + kappa_t**2 * np.einsum("ij,ij->i", rt, rt))
    return k_n * gn, k_t * shear, moment

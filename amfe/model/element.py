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


def bond_end_loads(normal, d_i, d_j, springs, u_i, u_j):
    """Force and moment vectors a bond puts on particle i's end, and their split.

    Minus the gradient of the energy 1/2 D.Du.D + 1/2 Dr.Dth.Dr (module
    docstring) with respect to particle i's DOFs:

        f_i = Du D                   force on i, applied at the contact point
        c   = Dth Dr                 couple of the torsion and bending springs
        m_i = c + d_i e x f_i        moment on i about its centre

    Particle j's end carries f_j = -f_i and m_j = -c + d_j e x f_i =
    L e x f_i - m_i about its own centre (L = d_i + d_j): the element is in
    equilibrium, so at a particle with every DOF free the loads of its bonds
    sum to zero.

    Parameters
    ----------
    normal : ndarray (M, 3)
        Unit vectors e from particle i to particle j.
    d_i, d_j : ndarray (M,)
        Lever arms: centre of i (of j) to the contact point [length].
    springs : (k_n, k_t, kappa_n, kappa_t), each ndarray (M,)
        Normal and shear spring stiffness [force / length], torsion and bending
        spring stiffness [force * length].
    u_i, u_j : ndarray (M, 6)
        DOFs (u_x, u_y, u_z, theta_x, theta_y, theta_z) of the two ends [length, rad].

    Returns
    -------
    dict of str -> ndarray
        ``force_i`` (M, 3) [force]; ``moment_i`` (M, 3) [force * length], about
        i's centre; ``axial`` (M,) [force]: f_i . e, positive in tension (the
        bond pulls i towards j); ``shear`` (M,) [force]: magnitude of f_i
        normal to e; ``torsion`` (M,) [force * length]: c . e, signed;
        ``bending`` (M,) [force * length]: magnitude of c normal to e.
    """
    e = np.asarray(normal, dtype=float)
    k_n, k_t, kappa_n, kappa_t = springs
    u_i, u_j = np.asarray(u_i, dtype=float), np.asarray(u_j, dtype=float)
    d_i, d_j = np.asarray(d_i, dtype=float)[:, None], np.asarray(d_j, dtype=float)[:, None]
    k_n, k_t, kappa_n, kappa_t = (np.asarray(v, dtype=float) for v in (k_n, k_t, kappa_n, kappa_t))
    gap = u_j[:, :3] - u_i[:, :3] + np.cross(e, d_i * u_i[:, 3:] + d_j * u_j[:, 3:])
    gn = np.einsum("ij,ij->i", gap, e)
    f_shear = k_t[:, None] * (gap - gn[:, None] * e)
    force = (k_n * gn)[:, None] * e + f_shear
    rot = u_j[:, 3:] - u_i[:, 3:]
    rn = np.einsum("ij,ij->i", rot, e)
    c_bend = kappa_t[:, None] * (rot - rn[:, None] * e)
    couple = (kappa_n * rn)[:, None] * e + c_bend
    return {"force_i": force, "moment_i": couple + d_i * np.cross(e, force),
            "axial": k_n * gn, "shear": np.linalg.norm(f_shear, axis=1),
            "torsion": kappa_n * rn, "bending": np.linalg.norm(c_bend, axis=1)}


def particle_resultants(n, i, j, normal, length, force_i, moment_i):
    """Sum of the bond loads on every particle: zero where every DOF is free.

    Parameters
    ----------
    n : int
        Number of particles.
    i, j : ndarray (M,) int
        End particles of each bond (0 <= i, j < n).
    normal : ndarray (M, 3)
        Unit vectors from i to j.
    length : ndarray (M,)
        Centre distances L = d_i + d_j [length].
    force_i, moment_i : ndarray (M, 3)
        As :func:`bond_end_loads` returns them.

    Returns
    -------
    force, moment : ndarray (n, 3)
        Sum of the bond forces on each particle [force] and of the bond
        moments about its centre [force * length]: the reactions where DOFs
        are prescribed.
    """
    force, moment = np.zeros((n, 3)), np.zeros((n, 3))
    np.add.at(force, i, force_i)
    np.add.at(force, j, -np.asarray(force_i))
    np.add.at(moment, i, moment_i)
    np.add.at(moment, j, np.asarray(length)[:, None] * np.cross(normal, force_i) - moment_i)
    return force, moment


def bond_forces(normal, d_i, d_j, springs, u_i, u_j):
    """Spring resultants of M bonds under particle DOFs u_i, u_j (M,6); springs: (k_n, k_t,
    kappa_n, kappa_t), each (M,) (:func:`bond_end_loads`).

    Returns (axial (M,), shear (M,), moment (M,)): the normal spring force
    (positive in tension) [force], the magnitude of the shear force at the
    contact point [force], and the magnitude of the torsion+bending couple
    [force*length] (the scalars of :func:`bond_end_loads`).
    """
    loads = bond_end_loads(normal, d_i, d_j, springs, u_i, u_j)
    return loads["axial"], loads["shear"], np.hypot(loads["torsion"], loads["bending"])

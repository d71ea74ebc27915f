"""The 12-DOF bond element: symmetry, definiteness, rigid modes, paper eq. 5, frame invariance."""
import numpy as np
import pytest

from amfe.model.element import bond_forces, element_matrices, local_element, local_frames


def _random_bonds(M=20, seed=0):
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(M, 3))
    e /= np.linalg.norm(e, axis=1)[:, None]
    L = rng.uniform(1.5, 2.0, M)
    d_i = rng.uniform(0.2, 0.8, M) * L
    springs = [rng.uniform(0.1, 3.0, M) for _ in range(4)]
    x_i = rng.normal(size=(M, 3))
    return e, L, d_i, L - d_i, springs, x_i, x_i + L[:, None] * e


def _rigid_modes(x_i, x_j):
    modes = []
    for a in range(3):
        v = np.zeros(12)
        v[a] = v[6 + a] = 1.0
        modes.append(v)
    for a in range(3):
        w = np.eye(3)[a]
        modes.append(np.r_[np.cross(w, x_i), w, np.cross(w, x_j), w])
    return np.array(modes).T


def test_symmetric_psd_six_rigid_zero_modes():
    e, L, d_i, d_j, k, x_i, x_j = _random_bonds()
    K = element_matrices(e, d_i, d_j, *k)
    assert np.array_equal(K, np.transpose(K, (0, 2, 1)))
    for m in range(len(e)):
        w, V = np.linalg.eigh(K[m])
        scale = w.max()
        assert w.min() > -1e-12 * scale
        zero = np.abs(w) < 1e-12 * scale
        assert zero.sum() == 6
        R = _rigid_modes(x_i[m], x_j[m])
        assert np.abs(K[m] @ R).max() < 1e-12 * scale * np.abs(R).max()
        # the null space is exactly the span of the rigid modes
        P = V[:, zero]
        assert np.linalg.matrix_rank(np.hstack([P, R]), tol=1e-8) == 6


def test_wrong_lever_arms_break_rigid_invariance():
    # the paper's single d0 is invariant only when d0 = L/2: unequal arms need both
    e, L, d_i, d_j, k, x_i, x_j = _random_bonds(M=1)
    K = element_matrices(e, d_i, L - d_i + 0.1, *k)
    R = _rigid_modes(x_i[0], x_j[0])
    assert np.abs(K[0] @ R[:, 3:]).max() > 1e-3


def test_equal_arms_give_the_papers_eq5():
    kn, kt, Kn, Kt, d0 = 2.0, 0.7, 0.3, 0.45, 0.9
    K = local_element(np.array([d0]), np.array([d0]), *(np.array([v]) for v in (kn, kt, Kn, Kt)))[0]
    K11 = np.array([[kn, 0, 0, 0, 0, 0], [0, kt, 0, 0, 0, kt * d0], [0, 0, kt, 0, -kt * d0, 0],
                    [0, 0, 0, Kn, 0, 0], [0, 0, -kt * d0, 0, Kt + kt * d0**2, 0],
                    [0, kt * d0, 0, 0, 0, Kt + kt * d0**2]])
    K12 = np.array([[-kn, 0, 0, 0, 0, 0], [0, -kt, 0, 0, 0, kt * d0], [0, 0, -kt, 0, -kt * d0, 0],
                    [0, 0, 0, -Kn, 0, 0], [0, 0, kt * d0, 0, kt * d0**2 - Kt, 0],
                    [0, -kt * d0, 0, 0, 0, kt * d0**2 - Kt]])
    K21 = np.array([[-kn, 0, 0, 0, 0, 0], [0, -kt, 0, 0, 0, -kt * d0], [0, 0, -kt, 0, kt * d0, 0],
                    [0, 0, 0, -Kn, 0, 0], [0, 0, -kt * d0, 0, kt * d0**2 - Kt, 0],
                    [0, kt * d0, 0, 0, 0, kt * d0**2 - Kt]])
    K22 = np.array([[kn, 0, 0, 0, 0, 0], [0, kt, 0, 0, 0, -kt * d0], [0, 0, kt, 0, kt * d0, 0],
                    [0, 0, 0, Kn, 0, 0], [0, 0, kt * d0, 0, kt * d0**2 + Kt, 0],
                    [0, -kt * d0, 0, 0, 0, kt * d0**2 + Kt]])
    paper = np.block([[K11, K12], [K21, K22]])
    assert np.allclose(K, paper, rtol=0, atol=1e-15)


def test_global_matrix_is_T_transpose_K_local_T_for_any_normal_axes():
    e, L, d_i, d_j, k, x_i, x_j = _random_bonds()
    K = element_matrices(e, d_i, d_j, *k)
    Kl = local_element(d_i, d_j, *k)
    rng = np.random.default_rng(5)
    for reference in (None, rng.normal(size=(len(e), 3))):
        Q = local_frames(e, reference)
        assert np.allclose(np.linalg.det(Q), 1.0)
        T = np.zeros((len(e), 12, 12))
        for b in range(4):
            T[:, 3 * b:3 * b + 3, 3 * b:3 * b + 3] = Q
        KT = np.einsum("mji,mjk,mkl->mil", T, Kl, T)
        assert np.allclose(KT, K, rtol=0, atol=1e-13 * np.abs(K).max())


def test_rotating_the_bed_rotates_the_forces():
    e, L, d_i, d_j, k, x_i, x_j = _random_bonds(seed=3)
    rng = np.random.default_rng(9)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))  # a proper rotation
    T = np.kron(np.eye(4), Q)
    K = element_matrices(e, d_i, d_j, *k)
    K_rot = element_matrices(e @ Q.T, d_i, d_j, *k)
    u = rng.normal(size=(len(e), 12))
    f = np.einsum("mij,mj->mi", K, u)
    f_rot = np.einsum("mij,mj->mi", K_rot, u @ T.T)
    assert np.allclose(f_rot, f @ T.T, atol=1e-12 * np.abs(f).max())


def test_bond_forces_from_the_gap():
    # pull particle j along the bond by delta: axial force k_n delta, nothing else
    e = np.array([[0.0, 0, 1]])
    ones = np.ones(1)
    u_i, u_j = np.zeros((1, 6)), np.zeros((1, 6))
    u_j[0, 2] = 1e-3
    axial, shear, moment = bond_forces(e, 0.8 * ones, 0.9 * ones,
                                       (5 * ones, 2 * ones, 3 * ones, 4 * ones), u_i, u_j)
    assert axial[0] == pytest.approx(5e-3) and shear[0] == 0 and moment[0] == 0
    # twist j about the bond: torque kappa_n theta, and bending about x: kappa_t theta
    u_j = np.zeros((1, 6))
    u_j[0, 5], u_j[0, 3] = 1e-3, 2e-3
    axial, shear, moment = bond_forces(e, 0.8 * ones, 0.9 * ones,
                                       (5 * ones, 2 * ones, 3 * ones, 4 * ones), u_i, u_j)
    # a rotation about x at j moves the contact point by theta x (-d_j e): shear 2 * 0.9 * 2e-3
    assert shear[0] == pytest.approx(2 * 0.9 * 2e-3)
    assert moment[0] == pytest.approx(np.hypot(3e-3, 8e-3))

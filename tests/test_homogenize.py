"""Tests of amfe.model.averages: Bagi averages, C, S and the engineering constants.

References are analytic or computed independently here (Delaunay tetrahedra,
tributary-area quadrature, direct uniaxial/shear solves of sigma = C eps).
"""
import itertools

import numpy as np
import pytest
from scipy.spatial import Delaunay

from amfe.errors import AmfeError
from amfe.model import averages as hz
from amfe.model import kubc


# --------------------------------------------------------------------------- #
# Point sets
# --------------------------------------------------------------------------- #
def cubic_lattice(n, s, origin=(0.0, 0.0, 0.0)):
    g = np.arange(n) * s
    x = np.array(list(itertools.product(g, g, g)), dtype=float)
    return x + np.asarray(origin)


def hcp_like(nx=6, ny=6, nz=4, r=12.5e-6, jitter=0.025, seed=3):
    """Triangular close-packed layers, ABAB stacking, every centre jittered."""
    rng = np.random.default_rng(seed)
    pts = []
    dz = 2 * r * np.sqrt(2.0 / 3.0)
    for k in range(nz):
        shift = np.array([r, r / np.sqrt(3.0)]) if k % 2 else np.zeros(2)
        for j in range(ny):
            for i in range(nx):
                xy = np.array([2 * r * i + r * (j % 2), np.sqrt(3.0) * r * j]) + shift
                pts.append([xy[0], xy[1], k * dz])
    x = np.array(pts)
    return x + rng.uniform(-jitter * r, jitter * r, size=x.shape)


def random_points(n=60, seed=0, scale=1e-4):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, scale, size=(n, 3)) + np.array([1e-3, -2e-3, 5e-4])


def delaunay_reference(x, u):
    """Volume-weighted mean gradient of the P1 interpolant, and the total volume."""
    tri = Delaunay(x)
    t = tri.simplices
    dx = (x[t[:, 1:]] - x[t[:, :1]]).transpose(0, 2, 1)   # (T, 3, 3), columns = edges
    du = (u[t[:, 1:]] - u[t[:, :1]]).transpose(0, 2, 1)
    vol = np.abs(np.linalg.det(dx)) / 6.0
    assert vol.min() > 1e-14 * np.ptp(x) ** 3, "reference needs a sliver-free point set"
    grad = du @ np.linalg.inv(dx)                          # (T, 3, 3)
    V = vol.sum()
    return np.einsum("t,tij->ij", vol, grad) / V, V


def rel(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b)


RNG = np.random.default_rng(12345)
H_AFFINE = RNG.normal(size=(3, 3)) * 1e-3     # deliberately not symmetric
C_AFFINE = RNG.normal(size=3) * 1e-6


# --------------------------------------------------------------------------- #
# Hull
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("points", ["random", "cubic", "hcp"])
def test_hull_is_outward_and_closed(points):
    x = {"random": random_points(), "cubic": cubic_lattice(5, 2e-5),
         "hcp": hcp_like()}[points]
    h = hz.hull_of(x)
    assert h.facets.shape == (h.areas.size, 3) and h.normals.shape == (h.areas.size, 3)
    # outward: facet centroid minus the interior centroid has positive projection
    c = x[h.vertices].mean(axis=0)
    fc = x[h.facets].mean(axis=1)
    keep = h.areas > 1e-12 * h.areas.max()
    assert np.all(np.einsum("fi,fi->f", fc - c, h.normals)[keep] > 0)
    # orientation of the vertex order agrees with the normal
    e = np.cross(x[h.facets[:, 1]] - x[h.facets[:, 0]], x[h.facets[:, 2]] - x[h.facets[:, 0]])
    assert np.allclose(e / 2.0, h.areas[:, None] * h.normals, rtol=0, atol=1e-12 * h.areas.max())
    assert np.allclose(np.linalg.norm(h.normals, axis=1), 1.0)
    # closed surface: sum A n = 0
    assert np.linalg.norm(h.areas @ h.normals) < 1e-12 * h.areas.sum()


def test_hull_volume_cube_lattice():
    n, s = 6, 3e-5
    h = hz.hull_of(cubic_lattice(n, s, origin=(1e-3, 2e-3, -1e-3)))
    assert h.volume == pytest.approx((n - 1) ** 3 * s ** 3, rel=1e-12)
    # cube corners are the only vertices that matter; area = 6 faces
    assert h.areas.sum() == pytest.approx(6 * ((n - 1) * s) ** 2, rel=1e-12)


def test_hull_volume_random_matches_delaunay():
    x = random_points(80, seed=7)
    h = hz.hull_of(x)
    _, V = delaunay_reference(x, np.zeros_like(x))
    assert h.volume == pytest.approx(V, rel=1e-12)


@pytest.mark.parametrize("x", [
    np.c_[np.random.default_rng(1).uniform(size=(20, 2)), np.full(20, 0.3)],  # plane z = 0.3
    np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 3.0]),                          # a line
    np.random.default_rng(2).uniform(size=(3, 3)),                             # 3 points
    np.zeros((8, 3)),                                                          # coincident
])
def test_hull_degenerate_raises(x):
    with pytest.raises(AmfeError, match="span no volume"):
        hz.hull_of(x)


def test_hull_tilted_plane_raises():
    rng = np.random.default_rng(4)
    uv = rng.uniform(size=(30, 2))
    a, b = np.array([1.0, 2.0, 0.5]), np.array([-0.3, 0.1, 1.0])
    with pytest.raises(AmfeError, match="span no volume"):
        hz.hull_of(uv[:, :1] * a + uv[:, 1:] * b + 7.0)


def test_hull_nonfinite_raises():
    x = random_points()
    x[3, 1] = np.nan
    with pytest.raises(AmfeError, match="non-finite"):
        hz.hull_of(x)


# --------------------------------------------------------------------------- #
# Bagi strain
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("points", ["random", "cubic", "hcp"])
def test_bagi_strain_affine_is_exact(points):
    x = {"random": random_points(), "cubic": cubic_lattice(6, 2.2e-5, origin=(1e-4, 0, 3e-4)),
         "hcp": hcp_like()}[points]
    u = x @ H_AFFINE.T + C_AFFINE
    H = hz.bagi_strain(hz.hull_of(x), u)
    assert rel(H, H_AFFINE) < 1e-12
    assert rel(hz.symmetric(H), 0.5 * (H_AFFINE + H_AFFINE.T)) < 1e-12


def test_bagi_strain_rigid_motion_is_zero_strain():
    x = hcp_like()
    W = np.array([[0.0, -3e-4, 2e-4], [3e-4, 0.0, -1e-4], [-2e-4, 1e-4, 0.0]])
    u = x @ W.T + np.array([1e-6, -2e-6, 5e-7])
    H = hz.bagi_strain(hz.hull_of(x), u)
    assert rel(H, W) < 1e-12
    assert np.linalg.norm(hz.symmetric(H)) < 1e-12 * np.linalg.norm(W)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bagi_strain_nonaffine_equals_delaunay_mean_gradient(seed):
    x = random_points(50, seed=seed)
    L = np.ptp(x)
    xi = (x - x.min(axis=0)) / L
    # smooth, strongly non-affine field (about 1e-6 of the size)
    u = 1e-6 * L * np.c_[np.sin(3 * xi[:, 0] + xi[:, 1]) * xi[:, 2],
                         np.cos(2 * xi[:, 1]) + xi[:, 0] ** 2,
                         np.exp(xi[:, 2]) * xi[:, 0] - xi[:, 1] ** 3]
    ref, V = delaunay_reference(x, u)
    h = hz.hull_of(x)
    assert h.volume == pytest.approx(V, rel=1e-12)
    H = hz.bagi_strain(h, u)
    assert rel(H, ref) < 1e-10
    # the non-affine part matters: the result is not the affine fit
    A = np.c_[x, np.ones(len(x))]
    fit = np.linalg.lstsq(A, u, rcond=None)[0][:3].T
    assert rel(H, fit) > 1e-3


def test_bagi_strain_reads_only_hull_vertices():
    x = cubic_lattice(5, 1e-5)
    h = hz.hull_of(x)
    rng = np.random.default_rng(9)
    u = rng.normal(size=x.shape) * 1e-7
    H1 = hz.bagi_strain(h, u)
    inner = np.setdiff1d(np.arange(len(x)), h.vertices)
    u2 = u.copy()
    u2[inner] += rng.normal(size=(inner.size, 3))
    assert np.array_equal(H1, hz.bagi_strain(h, u2))
    # and it does read the vertices
    u3 = u.copy()
    u3[h.vertices[0]] += 1e-6
    assert not np.allclose(hz.bagi_strain(h, u3), H1)


def test_kubc_on_lattice_gives_applied_strain():
    x = cubic_lattice(5, 2.5e-5)
    r = np.full(len(x), 1.6e-5)
    xc = hz.box_center(x)
    bnd = kubc.boundary_particles(x, r)
    h = hz.hull_of(x)
    assert bnd[h.vertices].all()          # every hull vertex is a boundary particle
    eps_cases = hz.unit_strains() * 1e-3
    for k, eps in enumerate(eps_cases):
        u = np.zeros_like(x)
        u[bnd] = kubc.kubc_displacements(x[bnd], xc, eps)
        u[~bnd] = RNG.normal(size=(np.count_nonzero(~bnd), 3))   # interior is irrelevant
        H = hz.bagi_strain(h, u)
        np.testing.assert_allclose(hz.voigt_strain(H), 1e-3 * np.eye(6)[k], rtol=0, atol=1e-15)


def test_bagi_strain_shape_errors():
    h = hz.hull_of(random_points(20))
    with pytest.raises(AmfeError):
        hz.bagi_strain(h, np.zeros((20, 2)))
    with pytest.raises(AmfeError):
        hz.bagi_strain(h, np.zeros((h.facets.max(), 3)))


# --------------------------------------------------------------------------- #
# Bagi stress
# --------------------------------------------------------------------------- #
def cube_boundary_nodes(a, m, origin):
    """Nodes of an m x m grid on every face of a cube of side a, with their
    tributary force vector sigma0-free part: (positions, sum over faces of w n)."""
    g = np.linspace(0.0, a, m)
    w1 = np.full(m, a / (m - 1))
    w1[[0, -1]] *= 0.5                                    # trapezoid weights
    nodes = {}
    for axis in range(3):
        others = [d for d in range(3) if d != axis]
        for side, sgn in ((0.0, -1.0), (a, 1.0)):
            n = np.zeros(3)
            n[axis] = sgn
            for i, j in itertools.product(range(m), range(m)):
                p = np.zeros(3)
                p[axis] = side
                p[others[0]], p[others[1]] = g[i], g[j]
                key = tuple(np.round(p / a * (m - 1)).astype(int))
                pos, an = nodes.get(key, (p, np.zeros(3)))
                nodes[key] = (pos, an + w1[i] * w1[j] * n)
    pos = np.array([v[0] for v in nodes.values()]) + np.asarray(origin)
    an = np.array([v[1] for v in nodes.values()])
    return pos, an


def test_bagi_stress_uniform_stress_recovered():
    a, m = 2e-4, 7
    origin = np.array([1e-3, -4e-4, 2e-4])
    pos, an = cube_boundary_nodes(a, m, origin)
    assert len(pos) == 6 * m * m - 12 * m + 8
    sigma0 = np.array([[3.0, 0.7, -1.1], [0.7, -2.0, 0.4], [-1.1, 0.4, 5.0]]) * 1e8
    f = an @ sigma0.T                                     # f = sigma0 (n A)
    assert np.linalg.norm(f.sum(axis=0)) < 1e-12 * np.abs(f).sum()
    xc = origin + a / 2
    sig = hz.bagi_stress(f, pos, xc, a ** 3)
    assert rel(sig, sigma0) < 1e-12
    assert hz.asymmetry(sig) < 1e-12
    # equilibrated forces: the reference point does not matter
    sig2 = hz.bagi_stress(f, pos, xc + np.array([3e-4, -1e-4, 7e-5]), a ** 3)
    assert rel(sig2, sigma0) < 1e-12


def test_bagi_stress_rotation_equivariant():
    rng = np.random.default_rng(5)
    f = rng.normal(size=(30, 3))
    x = rng.uniform(size=(30, 3)) * 1e-4
    xc = np.array([5e-5, 4e-5, 6e-5])
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    sig = hz.bagi_stress(f, x, xc, 2.5e-12)
    sigQ = hz.bagi_stress(f @ Q.T, x @ Q.T, Q @ xc, 2.5e-12)
    assert rel(sigQ, Q @ sig @ Q.T) < 1e-13
    # raw, not symmetrised, and scales as 1/V
    assert hz.asymmetry(sig) > 1e-2
    assert np.allclose(hz.bagi_stress(f, x, xc, 5e-12), sig / 2)
    # independent loop
    ref = sum(np.outer(f[b], x[b] - xc) for b in range(len(f))) / 2.5e-12
    assert rel(sig, ref) < 1e-13


def test_bagi_stress_bad_input():
    with pytest.raises(AmfeError):
        hz.bagi_stress(np.zeros((3, 3)), np.zeros((4, 3)), np.zeros(3), 1.0)
    with pytest.raises(AmfeError):
        hz.bagi_stress(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3), 0.0)


# --------------------------------------------------------------------------- #
# Voigt
# --------------------------------------------------------------------------- #
def test_voigt_conventions():
    T = np.arange(9.0).reshape(3, 3)
    # (xx, yy, zz, yz, xz, xy) of the symmetric part
    np.testing.assert_array_equal(hz.voigt(T), [0, 4, 8, (5 + 7) / 2, (2 + 6) / 2, (1 + 3) / 2])
    np.testing.assert_array_equal(hz.voigt_strain(T), [0, 4, 8, 12, 8, 4])
    e = np.array([1.0, 2.0, 3.0, 0.4, 0.6, 0.8])
    eps = hz.strain_from_voigt(e)
    np.testing.assert_array_equal(eps, [[1.0, 0.4, 0.3], [0.4, 2.0, 0.2], [0.3, 0.2, 3.0]])
    np.testing.assert_array_equal(hz.voigt_strain(eps), e)
    U = hz.unit_strains()
    assert U.shape == (6, 3, 3)
    assert U[3, 1, 2] == U[3, 2, 1] == 0.5 and np.count_nonzero(U[3]) == 2
    assert U[0, 0, 0] == 1.0 and np.count_nonzero(U[0]) == 1
    np.testing.assert_array_equal(np.array([hz.voigt_strain(u) for u in U]), np.eye(6))
    # energy consistency: sigma:eps == voigt(sigma) . voigt_strain(eps)
    rng = np.random.default_rng(0)
    s = hz.symmetric(rng.normal(size=(3, 3)))
    g = hz.symmetric(rng.normal(size=(3, 3)))
    assert np.sum(s * g) == pytest.approx(hz.voigt(s) @ hz.voigt_strain(g), rel=1e-14)


def test_kubc_displacements():
    rng = np.random.default_rng(3)
    x = rng.uniform(size=(10, 3))
    xc = np.array([0.5, 0.4, 0.6])
    eps = rng.normal(size=(3, 3))
    u = kubc.kubc_displacements(x, xc, eps)
    for b in range(10):
        np.testing.assert_allclose(u[b], eps @ (x[b] - xc), rtol=1e-14)


# --------------------------------------------------------------------------- #
# Stiffness, compliance, constants
# --------------------------------------------------------------------------- #
def isotropic_C(E, nu):
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[:3, :3] += 2 * mu * np.eye(3)
    C[3:, 3:] = mu * np.eye(3)
    return C


def orthotropic_S(c):
    S = np.zeros((6, 6))
    S[0, 0], S[1, 1], S[2, 2] = 1 / c["Ex"], 1 / c["Ey"], 1 / c["Ez"]
    S[1, 0] = S[0, 1] = -c["nu_xy"] / c["Ex"]
    S[2, 0] = S[0, 2] = -c["nu_xz"] / c["Ex"]
    S[2, 1] = S[1, 2] = -c["nu_yz"] / c["Ey"]
    S[3, 3], S[4, 4], S[5, 5] = 1 / c["G_yz"], 1 / c["G_xz"], 1 / c["G_xy"]
    return S


ORTHO = {"Ex": 210e9, "Ey": 120e9, "Ez": 40e9, "nu_yz": 0.35, "nu_xz": 0.12,
         "nu_xy": 0.27, "G_yz": 15e9, "G_xz": 22e9, "G_xy": 50e9}


def test_isotropic_constants():
    E, nu = 210e9, 0.28
    S, p = hz.compliance_and_constants(isotropic_C(E, nu))
    assert list(p) == ["Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy"]
    for k in ("Ex", "Ey", "Ez"):
        assert p[k] == pytest.approx(E, rel=1e-12)
    for k in ("nu_yz", "nu_xz", "nu_xy"):
        assert p[k] == pytest.approx(nu, rel=1e-12)
    for k in ("G_yz", "G_xz", "G_xy"):
        assert p[k] == pytest.approx(E / (2 * (1 + nu)), rel=1e-12)
    assert rel(S @ isotropic_C(E, nu), np.eye(6)) < 1e-12


def test_orthotropic_constants_and_index_convention():
    S0 = orthotropic_S(ORTHO)
    S, p = hz.compliance_and_constants(np.linalg.inv(S0))
    assert rel(S, S0) < 1e-12
    for k, v in ORTHO.items():
        assert p[k] == pytest.approx(v, rel=1e-11), k
    # the reciprocal ratios differ, so dividing by the wrong diagonal is caught
    nu_zy = ORTHO["nu_yz"] * ORTHO["Ez"] / ORTHO["Ey"]
    nu_zx = ORTHO["nu_xz"] * ORTHO["Ez"] / ORTHO["Ex"]
    nu_yx = ORTHO["nu_xy"] * ORTHO["Ey"] / ORTHO["Ex"]
    assert abs(p["nu_yz"] - nu_zy) > 0.1 and abs(p["nu_xz"] - nu_zx) > 0.05
    assert abs(p["nu_xy"] - nu_yx) > 0.05


def test_constants_by_direct_load_solves_nonsymmetric_C():
    """nu_ij and E_i from solving C eps = sigma for a uniaxial stress in i.

    C slightly non-symmetric, so S32 != S23 and a transposed index is caught.
    """
    rng = np.random.default_rng(11)
    C = np.linalg.inv(orthotropic_S(ORTHO))
    K = rng.normal(size=(6, 6))
    C = C + 0.05 * np.abs(C).max() * (K - K.T)           # skew part: sym(C) stays PD
    S, p = hz.compliance_and_constants(C)
    assert abs(S[2, 1] - S[1, 2]) > 1e-3 * abs(S[2, 1])
    axes = "xyz"
    for i in range(3):
        eps = np.linalg.solve(C, np.eye(6)[i])            # uniaxial unit stress along i
        assert p["E" + axes[i]] == pytest.approx(1 / eps[i], rel=1e-12)
        for j in range(3):
            key = f"nu_{axes[i]}{axes[j]}"
            if key in p:
                assert p[key] == pytest.approx(-eps[j] / eps[i], rel=1e-10), key
    for k, name in zip(range(3, 6), ("G_yz", "G_xz", "G_xy")):
        eps = np.linalg.solve(C, np.eye(6)[k])            # pure shear stress
        assert p[name] == pytest.approx(1 / eps[k], rel=1e-12)


def test_stiffness_recovers_C():
    rng = np.random.default_rng(21)
    A = rng.normal(size=(6, 6))
    C0 = A @ A.T + 6 * np.eye(6)
    C0[0, 1] += 0.3                                       # a bit non-symmetric
    strains = rng.normal(size=(6, 6)) * 1e-3              # rows = cases
    stresses = strains @ C0.T                             # sigma_k = C0 eps_k
    C, asym = hz.stiffness(strains, stresses)
    assert rel(C, C0) < 1e-12
    assert asym == pytest.approx(np.linalg.norm(C0 - C0.T) / np.linalg.norm(C0), rel=1e-10)
    # the unit cases give C's columns directly
    C2, asym2 = hz.stiffness(np.eye(6), isotropic_C(1.0, 0.3))
    assert rel(C2, isotropic_C(1.0, 0.3)) < 1e-15 and asym2 < 1e-15


def test_stiffness_singular_raises():
    rng = np.random.default_rng(2)
    strains = rng.normal(size=(6, 6))
    strains[5] = strains[0] + strains[2]
    with pytest.raises(AmfeError, match="do not span"):
        hz.stiffness(strains, rng.normal(size=(6, 6)))


def test_not_positive_definite_raises():
    C = isotropic_C(1e9, 0.3)
    C[3, 3] = -1e8
    with pytest.raises(AmfeError, match="not positive definite.*eigenvalues"):
        hz.compliance_and_constants(C)
    with pytest.raises(AmfeError, match="not positive definite"):
        hz.compliance_and_constants(np.zeros((6, 6)))
    C = isotropic_C(1e9, 0.3)
    C[2, 4] = np.nan
    with pytest.raises(AmfeError, match="non-finite"):
        hz.compliance_and_constants(C)


def test_symmetrise_and_asymmetry():
    rng = np.random.default_rng(8)
    C = rng.normal(size=(6, 6))
    Cs = hz.symmetrise(C)
    np.testing.assert_array_equal(Cs, Cs.T)
    np.testing.assert_allclose(Cs, (C + C.T) / 2)
    assert hz.asymmetry(Cs) == 0.0
    assert hz.asymmetry(np.zeros((3, 3))) == 0.0
    W = np.array([[0, 1.0, 0], [-1.0, 0, 0], [0, 0, 0]])
    assert hz.asymmetry(W) == pytest.approx(2.0)


def test_pipeline_uniform_continuum():
    """Affine boundary displacements + sigma = C0 eps tractions -> C0 back."""
    C0 = np.linalg.inv(orthotropic_S(ORTHO))
    a, m = 1e-4, 5
    origin = np.array([2e-4, 0.0, -1e-4])
    pos, an = cube_boundary_nodes(a, m, origin)
    h = hz.hull_of(pos)
    assert h.volume == pytest.approx(a ** 3, rel=1e-12)
    xc = hz.box_center(pos)
    strains, stresses = [], []
    for eps in hz.unit_strains() * 1e-4:
        u = kubc.kubc_displacements(pos, xc, eps)
        H = hz.bagi_strain(h, u)
        e = hz.voigt_strain(H)
        s = C0 @ e
        sigma = np.array([[s[0], s[5], s[4]], [s[5], s[1], s[3]], [s[4], s[3], s[2]]])
        f = an @ sigma.T
        sig = hz.bagi_stress(f, pos, xc, h.volume)
        assert hz.asymmetry(sig) < 1e-12
        strains.append(e)
        stresses.append(hz.voigt(sig))
    C, asym = hz.stiffness(np.array(strains), np.array(stresses))
    assert rel(C, C0) < 1e-11 and asym < 1e-11
    _, p = hz.compliance_and_constants(hz.symmetrise(C))
    for k, v in ORTHO.items():
        assert p[k] == pytest.approx(v, rel=1e-10), k


# --------------------------------------------------------------------------- #
# Boundary set
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("n, rfac, layers", [(6, 0.6, 1), (7, 1.3, 2), (4, 0.3, 1), (8, 2.4, 3)])
def test_boundary_particles_lattice_count(n, rfac, layers):
    s = 2.5e-5
    x = cubic_lattice(n, s, origin=(1e-3, -3e-4, 7e-5))
    rng = np.random.default_rng(n)
    r = rng.uniform(0.5, 1.0, size=len(x)) * rfac * s
    r[17] = rfac * s                                      # the maximum radius
    mask = kubc.boundary_particles(x, r)
    inner = max(n - 2 * layers, 0)
    assert mask.sum() == n ** 3 - inner ** 3
    # independent per-particle check via integer lattice indices
    idx = np.rint((x - x.min(axis=0)) / s).astype(int)
    ref = np.any((idx < layers) | (idx > n - 1 - layers), axis=1)
    np.testing.assert_array_equal(mask, ref)
    np.testing.assert_allclose(hz.box_center(x), x.min(axis=0) + (n - 1) * s / 2, rtol=1e-14)


def test_boundary_particles_distance_equal_to_radius_counts():
    x = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0], [1.5, 1.5, 1.5],
                  [1.5, 3.0, 3.0], [1.5, 1.0, 1.5]])
    r = np.full(len(x), 1.0)
    # bbox [0,3]^3; particle 4 sits at 1.5 from every face -> interior; 6 at 1.0 from y=0
    np.testing.assert_array_equal(kubc.boundary_particles(x, r),
                                  [True, True, True, True, False, True, True])

"""The PETSc KUBC solve against analytic values, an independent direct solve and invariants."""
import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays, scipy_kubc_stiffness

from amfe.model.averages import bagi_strain, hull_of, voigt_strain
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.model.loadcase import rigid_body_modes
from amfe.model.material import Material
from amfe.solvers.assembly import assemble_stiffness
from amfe.solvers.loadcases import solve_load_cases
from amfe.solvers.petsc import init_petsc

PETSc = init_petsc()


@pytest.fixture(scope="module")
def hcp_bed():
    return generate_bed(size=(100e-6, 100e-6, 60e-6), seed=3)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_simple_cubic_lattice_analytic(n):
    s = 1.8e-6
    x, r = cubic_lattice(n, spacing=s)
    res = homogenize_arrays(x, r, rtol=1e-12)
    frame = build_frame(x, r)
    k_n = frame.k_n[0] * frame.force_scale / frame.length_scale  # N/m, all bonds alike
    assert np.allclose(frame.k_n, frame.k_n[0], rtol=1e-14)
    # n^2 chains of n - 1 bonds; V: the spheres' box ((n-1) s + 2 r)^3, no longer the
    # centres' hull ((n-1) s)^3 (docs/model.md, section 5)
    V = ((n - 1) * s + 2 * r[0]) ** 3
    exact = k_n / s * n**2 / (n - 1) ** 2 * ((n - 1) * s) ** 3 / V
    p = res["properties"]
    for key in ("Ex", "Ey", "Ez"):
        assert p[key] == pytest.approx(exact, rel=1e-8)
    for key in ("nu_yz", "nu_xz", "nu_xy"):
        assert abs(p[key]) < 1e-8
    assert res["volume"] == pytest.approx(V, rel=1e-12)
    assert res["n_removed"] == 0 and res["n_bonds"] == 3 * n * n * (n - 1)


def test_kubc_bagi_strain_is_the_applied_strain(hcp_bed):
    frame = build_frame(hcp_bed.centers, hcp_bed.radii)
    groups = kubc_groups(frame)
    sol = solve_load_cases(frame, PETSc.COMM_WORLD, groups, rtol=1e-10)
    hull = hull_of(frame.centers)
    # every hull vertex is a boundary particle, so the strain is exact
    assert groups[0].fixed[hull.vertices, :3].all()
    for k in range(6):
        e = voigt_strain(bagi_strain(hull, sol.u[k][:, :3]))
        assert np.allclose(e, np.eye(6)[k], atol=1e-10, rtol=0)


def test_matches_independent_scipy_direct_solve(hcp_bed):
    res = homogenize_arrays(hcp_bed.centers, hcp_bed.radii, rtol=1e-12)
    frame = build_frame(hcp_bed.centers, hcp_bed.radii)
    C_ref = scipy_kubc_stiffness(frame) * frame.stress_scale
    C = np.array(res["C"])
    assert np.abs(C - C_ref).max() <= 1e-8 * np.abs(C_ref).max()
    # KUBC with free boundary rotations: reactions are forces only, stress symmetric
    assert res["solver"]["stress_asymmetry"] < 1e-8
    assert res["solver"]["C_asymmetry"] < 1e-8
    # the model's stiffness is of the order of the solid's (docs/model.md, section 5a; this
    # small bed reads softer in its own box than its hull), nu in a physical range
    p = res["properties"]
    assert 0.5 * 210e9 < p["Ex"] < 4 * 210e9
    assert 0 < p["nu_xy"] < 0.5


def test_free_frame_matrix_annihilates_rigid_body_modes(hcp_bed):
    frame = build_frame(hcp_bed.centers, hcp_bed.radii)
    A = assemble_stiffness(frame, PETSc.COMM_WORLD, 0, frame.n_particles)
    modes = rigid_body_modes(frame.centers)
    x, y = A.createVecs()
    scale = A.norm(PETSc.NormType.INFINITY)
    for m in modes:
        x.setArray(m)
        A.mult(x, y)
        assert y.norm(PETSc.NormType.INFINITY) < 1e-12 * scale * np.abs(m).max()
    # and exactly six: the smallest eigenvalues of the dense matrix
    if frame.n_particles <= 300:
        w = np.linalg.eigvalsh(A.convert("dense").getDenseArray())
        assert np.sum(np.abs(w) < 1e-10 * w.max()) == 6


def test_unit_and_material_invariance(hcp_bed):
    ref = homogenize_arrays(hcp_bed.centers, hcp_bed.radii, rtol=1e-12)
    big = homogenize_arrays(hcp_bed.centers * 1000, hcp_bed.radii * 1000, rtol=1e-12)
    soft = homogenize_arrays(hcp_bed.centers, hcp_bed.radii, Material(E=70e9), rtol=1e-12)
    for key, value in ref["properties"].items():
        assert big["properties"][key] == pytest.approx(value, rel=1e-9)
        scale = 70 / 210 if key[0] in "EG" else 1.0
        assert soft["properties"][key] == pytest.approx(value * scale, rel=1e-9)
    assert big["volume"] == pytest.approx(ref["volume"] * 1e9, rel=1e-12)


def test_floating_particles_removed_and_counted():
    x, r = cubic_lattice(4)
    ref = homogenize_arrays(x, r, rtol=1e-12)
    far = np.array([[50e-6, 0, 0], [60e-6, 0, 0], [61.5e-6, 0, 0]])  # one loner, one pair
    res = homogenize_arrays(np.vstack([far[:1], x, far[1:]]), np.r_[r[:1], r, r[:2]], rtol=1e-12)
    assert res["n_removed"] == 3 and res["n_particles"] == len(x) + 3
    for key, value in ref["properties"].items():
        assert res["properties"][key] == pytest.approx(value, rel=1e-10, abs=1e-12)


def test_sbaij_operator_equals_constrained_aij(hcp_bed):
    from amfe.model.kubc import boundary_particles
    from amfe.solvers.assembly import aij_from_blocks, local_block_rows, sbaij_operator
    frame = build_frame(hcp_bed.centers, hcp_bed.radii)
    n = frame.n_particles
    blocks = local_block_rows(frame, 0, n)
    fixed = np.zeros((n, 6), bool)
    fixed[boundary_particles(frame.centers, frame.radii), :3] = True
    fixed[::7, 4] = True  # and some rotations, as a general DOF mask
    A = aij_from_blocks(PETSc.COMM_WORLD, n, 0, n, *blocks)
    dofs = np.flatnonzero(fixed.ravel()).astype(PETSc.IntType)
    diag = A.getDiagonal()
    A.zeroRowsColumns(dofs, diag=1.0)
    d = A.getDiagonal()
    d.getArray()[dofs] = diag.getArray()[dofs]
    A.setDiagonal(d)
    S = sbaij_operator(PETSc.COMM_WORLD, n, 0, n, *blocks, fixed=fixed)
    dense_A = A.convert("dense").getDenseArray()
    x, y = A.createVecs()
    y2 = y.duplicate()
    for seed in range(3):
        x.setArray(np.random.default_rng(seed).normal(size=6 * n))
        A.mult(x, y)
        S.mult(x, y2)
        assert np.allclose(y2.getArray(), y.getArray(), rtol=0, atol=1e-13 * np.abs(dense_A).max())


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_block_rows_equal_dense_stiffness_bond_by_bond(hcp_bed, parts):
    """Each row range's two block-CSR parts (own columns, then the others) equal the
    dense global stiffness summed bond by bond from element_blocks (an independent
    assembly), with sorted columns in every row."""
    import scipy.sparse as sp

    from amfe.model.element import element_blocks
    from amfe.solvers.assembly import local_block_rows
    frame = build_frame(hcp_bed.centers, hcp_bed.radii)
    n, b = frame.n_particles, frame.bonds
    K = np.zeros((6 * n, 6 * n))
    Kii, Kij, Kjj = element_blocks(b.normal, b.d_i, b.d_j, frame.k_n, frame.k_t,
                                   frame.kappa_n, frame.kappa_t)
    for e, (i, j) in enumerate(zip(b.i, b.j)):
        K[6 * i:6 * i + 6, 6 * i:6 * i + 6] += Kii[e]
        K[6 * j:6 * j + 6, 6 * j:6 * j + 6] += Kjj[e]
        K[6 * i:6 * i + 6, 6 * j:6 * j + 6] += Kij[e]
        K[6 * j:6 * j + 6, 6 * i:6 * i + 6] += Kij[e].T
    tol = 1e-12 * abs(K).max()
    edges = np.linspace(0, n, parts + 1).astype(int)
    for r0, r1 in zip(edges[:-1], edges[1:]):
        indptr, cols, blocks = local_block_rows(frame, r0, r1)
        nloc = r1 - r0
        stacked = sp.bsr_matrix((blocks, cols, indptr), shape=(12 * nloc, 6 * n)).toarray()
        mine = K[6 * r0:6 * r1]
        own = np.zeros_like(mine)
        own[:, 6 * r0:6 * r1] = mine[:, 6 * r0:6 * r1]
        np.testing.assert_allclose(stacked[:6 * nloc], own, rtol=0, atol=tol)
        np.testing.assert_allclose(stacked[6 * nloc:], mine - own, rtol=0, atol=tol)
        for r in range(2 * nloc):
            assert np.all(np.diff(cols[indptr[r]:indptr[r + 1]]) > 0)

"""The voxel model (docs/model.md, section 10): element, geometry, mesh, PETSc solve, API, CLI."""
import json

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import brute_grip, run_cli, run_mpi_script

from amfe.errors import AmfeError
from amfe.model.bed import Bed, generate_bed
from amfe.model.bonds import find_bonds
from amfe.model.hex8 import (
    VERTICES,
    element_stiffness,
    isotropic_D,
    mean_strain_matrix,
    strain_matrix,
)
from amfe.model.material import Material
from amfe.model.options import SolveOptions
from amfe.model.voxel import (
    NECK_ERROR_SHARE,
    NECK_WARN_SHARE,
    Grid,
    VoxelSolid,
    grid_over,
    load_carrying,
    voxel_solid,
    voxelize,
)
from amfe.model.voxelmesh import block_rows, build_mesh

STEEL_E, STEEL_NU = 210e9, 0.28
SIDES = [np.ones(3), np.array([1.0, 0.8, 1.3])]


def solid_lattice(n=3, spacing=1e-5, radius=0.9e-5):
    """n^3 cubic lattice whose spheres (radius > spacing sqrt(3) / 2) fill their centres' box,
    which is the bed's recorded size (docs/model.md, section 5: V and KUBC's box)."""
    g = np.arange(n) * spacing
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return Bed(x, np.full(len(x), radius), {"size": [(n - 1) * spacing] * 3})


# ----------------------------------------------------------------------------- element
@pytest.mark.parametrize("h", SIDES)
def test_element_null_space_is_the_six_rigid_modes(h):
    K = element_stiffness(h, 1.0, 0.3)
    eig = np.linalg.eigvalsh(K)
    assert np.sum(np.abs(eig) < 1e-12 * eig.max()) == 6
    assert eig[6] > 1e-3 * eig.max()
    x = VERTICES * h
    for omega in np.eye(3):  # rotations and translations are annihilated
        assert np.abs(K @ np.cross(omega, x).ravel()).max() < 1e-12
        assert np.abs(K @ np.tile(omega, 8)).max() < 1e-12


@pytest.mark.parametrize("h", SIDES)
def test_patch_test_linear_field_gives_the_exact_constant_stress(h):
    rng = np.random.default_rng(0)
    G, c = rng.normal(size=(3, 3)), rng.normal(size=3)
    u = (VERTICES * h @ G.T + c).ravel()
    eps = 0.5 * (G + G.T)
    voigt = np.array([eps[0, 0], eps[1, 1], eps[2, 2], 2 * eps[1, 2], 2 * eps[0, 2], 2 * eps[0, 1]])
    D = isotropic_D(STEEL_E, STEEL_NU)
    for xi in rng.uniform(-1, 1, size=(5, 3)):
        assert np.allclose(D @ strain_matrix(xi, h) @ u, D @ voigt, rtol=1e-12, atol=1e-3)
    assert np.allclose(mean_strain_matrix(h) @ u, voigt, rtol=1e-12, atol=1e-14)
    # energy of the affine field: 1/2 u K u = 1/2 V eps : D : eps, exactly
    K = element_stiffness(h, STEEL_E, STEEL_NU)
    assert u @ K @ u == pytest.approx(np.prod(h) * voigt @ D @ voigt, rel=1e-12)


# ----------------------------------------------------------------------------- geometry
def test_voxelize_against_a_direct_test_of_every_voxel():
    rng = np.random.default_rng(3)
    x, r = rng.uniform(0, 1, size=(12, 3)), rng.uniform(0.1, 0.3, size=12)
    grid = grid_over(np.zeros(3), np.ones(3), 0.07)
    c = [grid.lo[k] + (np.arange(grid.n[k]) + 0.5) * grid.h[k] for k in range(3)]
    Z, Y, X = np.meshgrid(c[2], c[1], c[0], indexing="ij")
    p = np.stack([X, Y, Z], -1)
    want = np.zeros(grid.shape, bool)
    for xi, ri in zip(x, r):
        want |= np.sum((p - xi) ** 2, axis=-1) < ri ** 2
    assert np.array_equal(voxelize(x, r, grid), want)
    # periodic: the same spheres and their images one period away
    images = np.concatenate([x + s for s in np.stack(np.meshgrid(*[[-1, 0, 1]] * 3),
                                                     -1).reshape(-1, 3)])
    wrapped = np.zeros(grid.shape, bool)
    for xi, ri in zip(images, np.tile(r, 27)):
        wrapped |= np.sum((p - xi) ** 2, axis=-1) < ri ** 2
    assert np.array_equal(voxelize(x, r, grid, periodic=True), wrapped)


def test_floating_pieces_are_removed_and_counted():
    solid = np.ones((7, 7, 7), bool)
    solid[2:5, 2:5, 2:5] = False           # a cavity
    solid[3, 3, 3] = True                  # a voxel floating in it
    kept, pieces, voxels = load_carrying(solid)
    assert (pieces, voxels) == (1, 1) and not kept[3, 3, 3] and kept.sum() == solid.sum() - 1
    # periodic: two slabs joined only across the period are one piece; a lone voxel is not
    slab = np.zeros((6, 6, 6), bool)
    slab[:, :, 0] = slab[:, :, 5] = True
    slab[3, 3, 2] = True
    kept, pieces, voxels = load_carrying(slab, periodic=True)
    assert (pieces, voxels) == (1, 1) and kept[:, :, [0, 5]].all()


def test_neck_resolution_warning_and_error():
    bed = generate_bed(size=(100e-6, 100e-6, 60e-6), seed=1)
    a = np.sort(find_bonds(bed.centers, bed.radii).a)
    # share of necks with 2a >= 2 H: a >= H
    warn_h = np.quantile(a, 1.0 - 0.5 * (NECK_WARN_SHARE + NECK_ERROR_SHARE)) * 1.0000001
    geo = voxel_solid(bed.centers, bed.radii, warn_h)
    assert NECK_ERROR_SHARE <= geo.neck_share < NECK_WARN_SHARE
    assert any("necks" in w for w in geo.warnings)
    fine = voxel_solid(bed.centers, bed.radii, 0.5 * a.min())
    assert fine.neck_share == 1.0 and not any("necks" in w for w in fine.warnings)
    with pytest.raises(AmfeError, match="necks"):
        voxel_solid(bed.centers, bed.radii, a.max() * 1.01)


def two_blocks(pair=True, radius=0.9e-5):
    """Two 3^3 cubic blocks of spacing 1e-5 m, 6e-5 m apart in x (both held by KUBC's
    boundary set) and, with ``pair``, two bonded particles floating between them (on one
    line: held by nothing). radius 0.9e-5 m: solid blocks; 0.55e-5: necks the frame takes."""
    a, b = solid_lattice(), solid_lattice()
    x = [a.centers, b.centers + [8e-5, 0, 0]]
    if pair:
        x.append(np.array([[5e-5, 1e-5, 0.5e-5], [5e-5, 1e-5, 1.5e-5]]))
    x = np.concatenate(x)
    return Bed(x, np.full(len(x), radius))


def test_particles_and_box_follow_the_frames_carrying_rule():
    """docs/model.md, sections 5 and 10: the frame's pieces, its box and its V."""
    from amfe.model.carrying import bed_box
    from amfe.model.frame import build_frame
    bed = two_blocks(radius=0.55e-5)
    geo = voxel_solid(bed.centers, bed.radii, 0.2e-5)
    frame = build_frame(bed.centers, bed.radii)
    assert np.array_equal(geo.kept, np.sort(frame.kept)) and geo.kept.size == 54
    assert geo.removed["particles"] == frame.removed["particles"] == 2
    L = bed_box(bed.centers, bed.radii, None, geo.kept)[0]
    assert geo.grid.volume == pytest.approx(np.prod(L), rel=1e-12)
    assert np.allclose(geo.grid.lo, -0.55e-5, rtol=0, atol=1e-18)
    assert frame.volume * frame.length_scale ** 3 == pytest.approx(geo.grid.volume, rel=1e-12)
    # a recorded size that holds the centres is the box, at [0, L]
    sized = voxel_solid(bed.centers, bed.radii, 0.2e-5, size=[12e-5, 3e-5, 3e-5])
    assert np.array_equal(sized.grid.lo, np.zeros(3))
    assert sized.grid.volume == pytest.approx(12e-5 * 9e-10, rel=1e-12)


def test_a_floating_piece_inside_the_box_changes_no_constant():
    from amfe.solvers.voxel import homogenize_voxel
    C = [homogenize_voxel(two_blocks(pair), SolveOptions(rtol=1e-10), voxel_size=0.5e-5)
         for pair in (False, True)]
    assert (C[0].n_removed, C[1].n_removed) == (0, 2)
    assert C[1].volume == C[0].volume
    assert np.abs(C[1].C - C[0].C).max() <= 1e-12 * np.abs(C[0].C).max()


# ----------------------------------------------------------------------------- mesh
def element_dofs(mesh):
    """(n_solid, 24) DOFs of every solid element, element by element (x fastest)."""
    out = []
    for iz, iy, ix in zip(*np.nonzero(mesh.solid)):
        v = np.array([ix, iy, iz]) + VERTICES
        v = np.mod(v, mesh.n) if mesh.periodic else v
        ids = mesh.node_id[v[:, 0] + mesh.m[0] * (v[:, 1] + mesh.m[1] * v[:, 2])]
        out.append((3 * ids[:, None] + np.arange(3)).ravel())
    return np.array(out)


def direct_assembly(solid, K, periodic):
    """The stiffness summed element by element (scipy), node numbering of build_mesh."""
    mesh = build_mesh(solid, periodic)
    dofs = element_dofs(mesh)
    n = 3 * mesh.n_nodes
    return sp.csr_matrix((np.tile(K.ravel(), len(dofs)), (np.repeat(dofs, 24, axis=1).ravel(),
                                                          np.tile(dofs, 24).ravel())),
                         shape=(n, n)), mesh


@pytest.mark.parametrize("periodic", [False, True])
def test_block_rows_equal_element_by_element_assembly(periodic):
    solid = np.random.default_rng(5).uniform(size=(4, 5, 3)) < 0.6
    K = element_stiffness(np.array([1.0, 0.9, 1.2]), 1.0, 0.3)
    want, mesh = direct_assembly(solid, K, periodic)
    half = mesh.n_nodes // 2
    parts = [block_rows(mesh, K, a, b) for a, b in ((0, half), (half, mesh.n_nodes))]
    got = sp.vstack([sp.bsr_matrix((blk, col, ptr), shape=(3 * (b - a), want.shape[1]))
                     for (ptr, col, blk), (a, b) in zip(parts, ((0, half), (half, mesh.n_nodes)))])
    assert abs(got - want).max() < 1e-14
    assert all(np.all(np.diff(col[p0:p1]) > 0) for ptr, col, _ in parts
               for p0, p1 in zip(ptr[:-1], ptr[1:]))


# ----------------------------------------------------------------------------- solver
def test_fully_solid_box_gives_the_particles_C_from_a_zero_guess():
    from amfe.solvers.voxel import homogenize_voxel
    m = Material(E=200e9, nu=0.3)
    res = homogenize_voxel(solid_lattice(), SolveOptions(rtol=1e-12, material=m),
                           voxel_size=0.5e-5, initial="zero")
    assert res.extra["model"]["solid_fraction"] == 1.0
    assert min(res.solver["iterations"]) > 0
    assert np.abs(np.array(res.C) - isotropic_D(m.E, m.nu)).max() <= 1e-10 * m.E


def test_fully_solid_periodic_box_gives_the_particles_C():
    from amfe.solvers.voxel import homogenize_voxel
    lattice = solid_lattice(n=5, spacing=1e-5, radius=0.9e-5)   # the period must exceed 4 R
    bed = Bed(lattice.centers, lattice.radii, {"periodic": [5e-5] * 3})
    res = homogenize_voxel(bed, SolveOptions(bc="periodic", rtol=1e-12), voxel_size=0.5e-5)
    assert res.bc == "periodic" and res.extra["model"]["solid_fraction"] == 1.0
    assert np.abs(np.array(res.C) - isotropic_D(STEEL_E, STEEL_NU)).max() <= 1e-10 * STEEL_E


def test_floating_piece_changes_nothing_once_removed():
    """A box with a cavity, with and without a voxel floating in it: the same C."""
    from amfe.solvers.petsc import init_petsc
    from amfe.solvers.voxel import voxel_stiffness
    PETSc = init_petsc()
    grid = Grid(lo=np.zeros(3), n=np.array([6, 6, 6]), h=np.full(3, 1e-6))
    cavity = np.ones(grid.shape, bool)
    cavity[2:5, 1:5, 1:5] = False
    blob = cavity.copy()
    blob[3, 3, 3] = True                  # no face shared with the walls
    Cs = []
    for solid in (cavity, blob):
        kept, pieces, voxels = load_carrying(solid)
        geo = VoxelSolid(grid=grid, solid=kept, kept=np.arange(1), n_bonds=0, n_bonds_input=0,
                         neck_share=1.0, solid_fraction=float(kept.mean()), pieces_removed=pieces,
                         voxels_removed=voxels, warnings=[])
        Cs.append(voxel_stiffness(geo, SolveOptions(rtol=1e-12, material=Material()),
                                  PETSc.COMM_SELF)[0])
        assert pieces == (1 if solid is blob else 0)
    assert np.abs(Cs[0] - Cs[1]).max() <= 1e-10 * STEEL_E


def scipy_voxel_C(geo, periodic, E=STEEL_E, nu=STEEL_NU, bed=None):
    """C [Pa] of a VoxelSolid by scipy's sparse LU on the element-by-element matrix, twice:
    from the work (KUBC: the reactions'; periodic: W0 - F . w) and from the volume
    average of the element stresses over the box (docs/model.md, section 10)."""
    from scipy.sparse.linalg import splu

    from amfe.model.averages import unit_strains
    h = geo.grid.h / geo.grid.h[0]
    Ke = element_stiffness(h, 1.0, nu)
    K, mesh = direct_assembly(geo.solid, Ke, periodic)
    dofs = element_dofs(mesh)
    x = mesh.node_ijk(np.arange(mesh.n_nodes)) * h
    V = np.prod(geo.grid.n * h)
    n = K.shape[0]
    if not periodic:
        spheres = ((None, None) if geo.grip_particles is None else
                   (bed.centers[geo.grip_particles], bed.radii[geo.grip_particles]))
        fixed = (3 * brute_grip(mesh, geo, *spheres)[:, None] + np.arange(3)).ravel()
        g = np.array([((x - geo.grid.n * h / 2) @ e.T).ravel() for e in unit_strains()])
        g[:, np.setdiff1d(np.arange(n), fixed)] = 0.0
        free = np.setdiff1d(np.arange(n), fixed)
        u = g.copy()
        u[:, free] = splu(K[free][:, free].tocsc()).solve(-(K[free][:, fixed] @ g[:, fixed].T)).T
        work, elements = g @ (K @ u.T), u[:, dofs]                 # (6, n_e, 24)
    else:
        q = np.array([((VERTICES * h) @ e.T).ravel() for e in unit_strains()])
        F = np.zeros((6, n))
        np.subtract.at(F, (slice(None), dofs), (Ke @ q.T).T[:, None, :])
        free = np.arange(3, n)                 # node 0's translations pinned
        w = np.zeros((6, n))
        w[:, free] = splu(K[free][:, free].tocsc()).solve(F[:, free].T.copy()).T
        work = len(dofs) * q @ Ke @ q.T - F @ w.T
        elements = w[:, dofs] + q[:, None, :]
    strain = np.einsum("ij,kej->ki", mean_strain_matrix(h), elements) * np.prod(h) / V
    return work / V * E, (isotropic_D(1.0, nu) @ strain.T) * E


@pytest.mark.parametrize("periodic", [False, True])
def test_petsc_solve_equals_an_independent_scipy_solve(periodic):
    from amfe.solvers.petsc import init_petsc
    from amfe.solvers.voxel import voxel_stiffness
    bed = generate_bed(size=(60e-6, 60e-6, 50e-6), seed=2, periodic=True)
    geo = voxel_solid(bed.centers, bed.radii, 5e-6, bed.attrs["periodic"] if periodic else None)
    bc = "periodic" if periodic else "kubc"
    C = voxel_stiffness(geo, SolveOptions(bc=bc, rtol=1e-10, material=Material()),
                        init_petsc().COMM_SELF)[0]
    want, averaged = scipy_voxel_C(geo, periodic, bed=bed)
    assert np.abs(C - want).max() <= 1e-8 * np.abs(want).max()
    assert np.abs(averaged - want).max() <= 1e-10 * np.abs(want).max()  # the same C
    # a loose solve: the second-order correction leaves a small fraction of its own size
    C, sol, _ = voxel_stiffness(geo, SolveOptions(bc=bc, rtol=1e-4, material=Material()),
                                init_petsc().COMM_SELF)
    error = np.abs(C - want).max() / np.abs(want).max()
    assert error < 0.05 * sol["stats"]["correction"] and error < 1e-6


@pytest.fixture(scope="module")
def bed_result():
    from amfe.solvers.voxel import homogenize_voxel
    bed = generate_bed(size=(100e-6, 100e-6, 60e-6), seed=1)
    return homogenize_voxel(bed, SolveOptions(rtol=1e-10), voxel_size=5e-6).to_dict()


def test_kubc_C_of_a_bed_is_below_the_voigt_bound(bed_result):
    C = np.array(bed_result["C"])
    phi = bed_result["model"]["solid_fraction"]
    assert 0.3 < phi < 1.0
    Cs = isotropic_D(STEEL_E, STEEL_NU)
    rng = np.random.default_rng(1)
    for e in np.concatenate([np.eye(6), rng.normal(size=(20, 6))]):
        assert e @ C @ e <= phi * e @ Cs @ e * (1 + 1e-9)
        assert e @ C @ e > 0.05 * phi * e @ Cs @ e     # and not a vanishing solid
    assert bed_result["solver"]["C_asymmetry"] < 1e-8


def test_result_follows_the_schema_and_api_dispatch(bed_result, tmp_path):
    import amfe
    from amfe.io.result_meta import validate
    pytest.importorskip("jsonschema")
    validate(bed_result)
    assert bed_result["model"]["grip"]["nodes"] > 0   # KUBC: gripped where the frame grips
    bed = generate_bed(size=(100e-6, 100e-6, 60e-6), seed=1)
    res = amfe.homogenize(bed, model="voxel", voxel_size=5e-6, rtol=1e-10)
    assert res.extra["model"]["name"] == "voxel"
    assert np.allclose(res.C, bed_result["C"], rtol=1e-12, atol=0)
    # KUBC on the frame's box: the recorded size [0, L], V and the particles the frame's
    frame = amfe.homogenize(bed)
    assert res.extra["model"]["box"]["min"] == [0.0, 0.0, 0.0]
    assert res.volume == pytest.approx(frame.volume, rel=1e-12)
    assert res.n_removed == frame.n_removed
    with pytest.raises(AmfeError, match="voxel model solves"):
        amfe.homogenize(bed, model="voxel", bc="subc")
    with pytest.raises(AmfeError, match="model must be"):
        amfe.homogenize(bed, model="beam")
    with pytest.raises(AmfeError, match="CG \\+ GAMG"):
        amfe.homogenize(bed, model="voxel", solver="cholesky")
    with pytest.raises(AmfeError, match="ParaView"):
        amfe.homogenize(bed, model="voxel", vtu_dir=str(tmp_path / "vtu"))
    with pytest.raises(AmfeError, match="not periodic"):
        amfe.homogenize(bed, model="voxel", bc="periodic")
    bad = dict(bed_result, model={**bed_result["model"], "solid_fraction": 1.5})
    with pytest.raises(AmfeError, match="model"):
        validate(bad)


def test_memory_estimate_refuses_before_allocating():
    from amfe.solvers.voxel import homogenize_voxel
    bed = solid_lattice()
    with pytest.raises(AmfeError, match="memory"):       # the grid alone: 8e12 voxels
        homogenize_voxel(bed, voxel_size=1e-9)
    # the grid and the frame's estimate of 27 particles (0.5 MB) fit, the 125 nodes' 2 MB not
    with pytest.raises(AmfeError, match="nodes"):
        homogenize_voxel(bed, SolveOptions(max_memory=1_000_000), voxel_size=0.5e-5)


# ----------------------------------------------------------------------------- MPI
@pytest.mark.mpi
def test_one_and_two_ranks_agree(tmp_path):
    script = tmp_path / "ranks.py"
    script.write_text(
        "import json\n"
        "from mpi4py import MPI\n"
        "from amfe.model.bed import Bed, generate_bed\n"
        "from amfe.model.options import SolveOptions\n"
        "from amfe.solvers.voxel import homogenize_voxel\n"
        "bed = generate_bed(size=(60e-6, 60e-6, 50e-6), seed=2, periodic=True)\n"
        "out = {}\n"
        "for name in ('kubc', 'periodic'):\n"
        "    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):\n"
        "        r = homogenize_voxel(bed, SolveOptions(bc=name, rtol=1e-10), comm,\n"
        "                             voxel_size=5e-6)\n"
        "        out[f'{name}{r.ranks}'] = r.C.tolist()\n"
        "from amfe.errors import AmfeError\n"
        "try:\n"   # a rank-dependent bed: the same error on both ranks, no hang
        "    homogenize_voxel(Bed(bed.centers, bed.radii * (1 + 1e-3 * MPI.COMM_WORLD.rank)))\n"
        "except AmfeError as exc:\n"
        "    out['error'] = str(exc)\n"
        "out['errors'] = MPI.COMM_WORLD.allgather('error' in out)\n"
        "if MPI.COMM_WORLD.rank == 0: print(json.dumps(out))\n")
    proc = run_mpi_script(script)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out.pop("errors") == [True, True] and "different inputs" in out.pop("error")
    out = {k: np.array(v) for k, v in out.items()}
    for name in ("kubc", "periodic"):
        scale = np.abs(out[f"{name}1"]).max()
        assert np.abs(out[f"{name}2"] - out[f"{name}1"]).max() <= 1e-8 * scale


@pytest.mark.mpi
def test_cli_voxel_model(tmp_path):
    from amfe.io.bedfile import write_bed
    path = tmp_path / "bed.h5"
    write_bed(path, generate_bed(size=(100e-6, 100e-6, 60e-6), seed=1))
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(path), "--model", "voxel", "--voxel-size", "5e-6",
                    "-o", str(out), "--quiet"], ranks=2)
    assert proc.returncode == 0, proc.stderr
    r = json.loads(out.read_text())
    assert r["model"]["name"] == "voxel" and r["ranks"] == 2 and "model: voxel" in proc.stdout
    bad = run_cli(["homogenize", str(path), "--model", "voxel", "--voxel-size", "5e-5"])
    assert bad.returncode == 2 and "necks" in bad.stderr and "Traceback" not in bad.stderr

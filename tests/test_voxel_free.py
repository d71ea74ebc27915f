"""The voxel model's matrix-free operator (docs/model.md, section 10, "Matrix-free operator").

The shell's product must be the assembled matrix's on every rank split, its
diagonal the matrix's diagonal, the coarse grid and interpolation must keep
what a two-grid method needs, and the constants must equal the assembled
path's on 1 and 2 ranks, KUBC and periodic.
"""
import json

import numpy as np
import pytest
from helpers import run_cli, run_mpi_script
from test_voxel import direct_assembly

from amfe.errors import AmfeError
from amfe.model.hex8 import element_stiffness
from amfe.model.voxel import grid_over
from amfe.model.voxelmesh import build_mesh
from amfe.model.voxelmg import coarse_grip, coarse_mesh, element_lists, prolongation

KE = element_stiffness(np.array([1.0, 0.9, 1.2]), 1.0, 0.3)


def random_solid(shape=(5, 6, 4), seed=5, share=0.6):
    return np.random.default_rng(seed).uniform(size=shape) < share


@pytest.mark.parametrize("periodic", [False, True])
def test_element_lists_of_node_ranges_partition_the_solid_elements(periodic):
    mesh = build_mesh(random_solid((4, 6, 6)), periodic)
    cuts = [0, 7, mesh.n_nodes // 2, mesh.n_nodes]
    parts = [element_lists(mesh, a, b)[0] for a, b in zip(cuts[:-1], cuts[1:])]
    assert sum(len(p) for p in parts) == mesh.n_elements
    assert np.array_equal(np.concatenate(parts), element_lists(mesh)[0])
    for p, a, b in zip(parts, cuts[:-1], cuts[1:]):
        assert np.all((p[:, 0] >= a) & (p[:, 0] < b))          # vertex 0 owned


@pytest.mark.parametrize("periodic", [False, True])
@pytest.mark.parametrize("fixed", [False, True])
def test_the_shell_product_and_diagonal_are_the_assembled_matrix(periodic, fixed):
    from amfe.solvers.petsc import init_petsc
    from amfe.solvers.voxelfree import ElementProduct, shell
    PETSc = init_petsc()
    solid = random_solid((4, 6, 6))
    K, mesh = direct_assembly(solid, KE, periodic)
    K = K.toarray()
    dofs = np.array([0, 1, 2, 7, 30, 31, 3 * mesh.n_nodes - 1]) if fixed else None
    free = ElementProduct(PETSc.COMM_SELF, mesh, KE, 0, mesh.n_nodes)
    A = shell(PETSc.COMM_SELF, free.with_fixed(dofs) if fixed else free)
    if fixed:
        keep = np.ones(len(K), bool)
        keep[dofs] = False
        K = K * np.outer(keep, keep)
        K[dofs, dofs] = 1.0
    u = np.random.default_rng(1).normal(size=len(K))
    x, y, d = A.createVecRight(), A.createVecLeft(), A.createVecLeft()
    x.setArray(u)
    A.mult(x, y)
    A.getDiagonal(d)
    assert np.abs(y.getArray() - K @ u).max() <= 1e-13 * np.abs(K).max() * np.abs(u).max()
    assert np.abs(d.getArray() - np.diag(K)).max() <= 1e-14 * np.abs(K).max()
    assert np.array_equal(x.getArray(), u)                    # the input is left alone


def test_the_coarse_grid_keeps_the_solid_and_the_grip():
    solid = random_solid((5, 7, 6))
    fine = build_mesh(solid)
    coarse = coarse_mesh(fine)
    assert np.array_equal(coarse.n, [3, 4, 3])                # odd counts round up
    assert 8 * coarse.solid.sum() == pytest.approx(solid.sum(), abs=1e-12)
    assert coarse.n_elements == np.count_nonzero(coarse.solid)
    grip = np.zeros(tuple(fine.m[::-1]), bool)
    grip[0], grip[:, :, 6] = True, True                       # the z = 0 face, the x = 6 face
    cg = coarse_grip(grip, coarse)
    assert cg.shape == tuple(coarse.m[::-1])
    for k, j, i in np.ndindex(cg.shape):   # the fine grip at the even nodes, void past the box
        inside = 2 * k < grip.shape[0] and 2 * j < grip.shape[1] and 2 * i < grip.shape[2]
        assert cg[k, j, i] == (inside and grip[2 * k, 2 * j, 2 * i])
    assert cg[0, :4, :].all() and cg[:3, :4, 3].all()
    with pytest.raises(AmfeError, match="even counts"):
        coarse_mesh(build_mesh(random_solid((4, 6, 5)), periodic=True))
    assert np.array_equal(grid_over(np.zeros(3), [5.0, 6.0, 7.0], 1.0, even=True).n, [6, 6, 8])


@pytest.mark.parametrize("periodic", [False, True])
def test_interpolation_keeps_translations_and_linear_fields_inside(periodic):
    solid = random_solid((6, 6, 8), share=0.8) if not periodic else random_solid((6, 6, 8))
    fine = build_mesh(solid, periodic)
    coarse = coarse_mesh(fine)
    P = prolongation(fine, coarse)
    assert P.shape == (fine.n_nodes, coarse.n_nodes)
    assert np.allclose(P.sum(axis=1), 1.0, rtol=0, atol=1e-14) and P.min() >= 0
    if periodic:
        return
    # a linear field on the coarse nodes is reproduced where all 8 coarse neighbours are active
    xc = coarse.node_ijk(np.arange(coarse.n_nodes)) * 2.0
    xf = fine.node_ijk(np.arange(fine.n_nodes)).astype(float)
    a = np.array([0.3, -1.1, 0.7])
    whole = np.asarray((P > 0).sum(axis=1)).ravel() == 2 ** (fine.node_ijk(
        np.arange(fine.n_nodes)) % 2).sum(axis=1)
    assert whole.sum() > fine.n_nodes // 2
    assert np.abs((P @ (xc @ a) - xf @ a)[whole]).max() < 1e-12


@pytest.mark.mpi
@pytest.mark.parametrize("ranks", [1, 2])
def test_matrix_free_constants_equal_the_assembled_ones(tmp_path, ranks):
    """KUBC on a scanned window and the periodic condition on a periodic bed, at rtol 1e-10:
    the two operators' C agree to 1e-8 on 1 and 2 ranks."""
    beds = {"kubc": ["--size", "0.08", "0.08", "0.05", "--seed", "1", "--track-width", "0.03",
                     "--hatch-spacing", "0.035"],
            "periodic": ["--periodic", "--size", "0.06", "0.06", "0.05", "--seed", "2"]}
    for bc, args in beds.items():
        bed = tmp_path / f"{bc}.h5"
        assert run_cli(["pack", *args, "-o", str(bed)]).returncode == 0
        C = {}
        for op in ("assembled", "matrix-free"):
            out = tmp_path / f"{bc}_{op}_{ranks}.json"
            proc = run_cli(["homogenize", str(bed), "--model", "voxel", "--bc", bc,
                            "--voxel-operator", op, "--rtol", "1e-10", "-o", str(out),
                            "--quiet"], ranks=ranks)
            assert proc.returncode == 0, proc.stderr
            res = json.loads(out.read_text())
            C[op] = np.array(res["C"])
            assert res["solver"]["operator"] == op
            assert max(res["solver"]["iterations"]) < 60
        scale = np.abs(C["assembled"]).max()
        assert np.abs(C["assembled"] - C["matrix-free"]).max() <= 1e-8 * scale


def test_the_operator_option_needs_the_voxel_model(tmp_path):
    proc = run_cli(["homogenize", "nothing.h5", "--voxel-operator", "matrix-free"])
    assert proc.returncode == 2 and "--model voxel" in proc.stderr


ODD_GRIP = """
import json, sys
import numpy as np
from amfe.model.material import Material
from amfe.model.options import SolveOptions
from amfe.model.voxel import VoxelSolid, grid_over
from amfe.solvers.petsclib import PETSc
from amfe.solvers.voxel import voxel_stiffness
solid = np.ones((7, 6, 9), bool)                  # (nz, ny, nx): two blocks, x < 4 and x > 4
solid[:, :, 4] = {joined}
grip = np.zeros((8, 7, 10), bool)
grip[:, :, 0] = True                              # the left block: its whole x = 0 face
grip[1::2, 1::2, 9] = True                        # the right block: odd nodes of x = 9 only
geo = VoxelSolid(grid=grid_over(np.zeros(3), np.array([9.0, 6, 7]) * 1e-6, 1e-6), solid=solid,
                 kept=np.arange(1), n_bonds=0, n_bonds_input=0, neck_share=1.0,
                 solid_fraction=float(solid.mean()), pieces_removed=0, voxels_removed=0,
                 warnings=[], grip=grip)
opts = SolveOptions(bc="kubc", material=Material(E=1e9, nu=0.3), rtol=1e-10)
out = {{}}
for op in ("assembled", "matrix-free"):
    C, sol, _ = voxel_stiffness(geo, opts, PETSc.COMM_WORLD, operator=op)
    out[op] = {{"C": C.tolist(), "iterations": sol["iterations"]}}
if PETSc.COMM_WORLD.getRank() == 0:
    print(json.dumps(out))
"""


@pytest.mark.mpi
@pytest.mark.parametrize("ranks", [1, 2])
@pytest.mark.parametrize("joined", [False, True])
def test_a_piece_gripped_only_at_odd_nodes_has_no_coarse_grip_and_still_converges(
        tmp_path, ranks, joined):
    """The coarse grid grips the fine grip's even nodes (coarse_grip). Here the right block
    (alone, or joined to the left one through a slab) is held only at odd nodes of an odd
    face, so its coarse image floats: the coarse operator is singular there. CG must still
    reach the assembled C (the coarse correction only preconditions)."""
    from amfe.model.voxelmesh import build_mesh
    grip = np.zeros((8, 7, 10), bool)
    grip[1::2, 1::2, 9] = True
    assert not coarse_grip(grip, coarse_mesh(build_mesh(np.ones((7, 6, 9), bool)))).any()
    script = tmp_path / "odd_grip.py"
    script.write_text(ODD_GRIP.format(joined=joined))
    proc = run_mpi_script(script, ranks=ranks)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    A, F = (np.array(got[op]["C"]) for op in ("assembled", "matrix-free"))
    assert np.abs(A - F).max() <= 1e-8 * np.abs(A).max()
    assert max(got["matrix-free"]["iterations"]) < 60
    if joined:                                    # held at both ends: a stiff solid in x
        assert A[0, 0] > 0.1 * 1e9

"""The voxel model's matrix-free operator and its two-grid preconditioner, on PETSc.

docs/model.md, section 10 ("Matrix-free operator"). The fine stiffness is a
PETSc shell matrix: each rank holds its elements' node lists
(:func:`amfe.model.voxelmg.element_lists`: the elements whose lowest corner
it owns), and K u gathers each element's 24 displacements, multiplies them
by Ke and sums the results back by node (in chunks), after the ghost values
arrive by a PETSc scatter; the contributions to other ranks' nodes go back
by the reverse scatter (ADD).
Prescribed DOFs act as in the assembled path's zeroRowsColumns: their
columns are zeroed before the product and their rows return the input.

The preconditioner is PETSc's PCMG on two levels: the shell with Chebyshev +
Jacobi smoothing (its diagonal is summed from diag(Ke)), and the coarse grid
of :func:`amfe.model.voxelmg.coarse_mesh`, assembled and solved by one GAMG
cycle with the rigid-body near null space. Options: the usual prefixes
(``-mg_levels_ksp_max_it``, ``-mg_coarse_pc_type``, ...) on top of these.
"""
import copy

import numpy as np
import scipy.sparse as sp

from amfe.model.voxelmesh import block_rows
from amfe.model.voxelmg import coarse_grip, coarse_mesh, element_lists, prolongation
from amfe.solvers.partition import row_ranges
from amfe.solvers.petsclib import PETSc


class ElementProduct:
    """Context of a PETSc shell matrix: K (or K with prescribed DOFs as identity rows and
    columns) of the mesh's elements [units of Ke]; ``fixed``: local prescribed DOFs
    (:meth:`with_fixed` makes the constrained one from the free one)."""

    CHUNK = 1 << 16
    """Elements per pass of the product (about 25 MB of temporaries)."""

    def __init__(self, comm, mesh, Ke, r0, r1, fixed=None):
        self.Ke, self.comm, self.r0 = Ke, comm, r0
        self.fixed = np.zeros(0, np.int64) if fixed is None else np.asarray(fixed, np.int64)
        self.n_local = 3 * (r1 - r0)
        conn, self.weights = element_lists(mesh, r0, r1)
        self.uniform = bool(np.all(self.weights == 1.0))
        needed = np.unique(conn)
        # ghost numbering: sorted node numbers, so a chunk of elements (sorted by vertex 0)
        # touches a narrow window of it
        self.conn = np.searchsorted(needed, conn).astype(np.int32)          # (n_e, 8)
        self.n_elements, self.n_ghost = len(conn), len(needed)
        gidx = (3 * needed[:, None] + np.arange(3)).ravel().astype(PETSc.IntType)
        self.ghost = PETSc.Vec().createSeq(3 * len(needed), comm=PETSc.COMM_SELF)
        self.ghost_out = self.ghost.duplicate()
        template = PETSc.Vec().createMPI((self.n_local, PETSc.DECIDE), comm=comm)
        self.work = template.duplicate()     # made here: a Vec's creation is collective
        iset = PETSc.IS().createGeneral(gidx, comm=PETSc.COMM_SELF)
        self.scatter = PETSc.Scatter().create(template, iset, self.ghost, None)
        self.diag_ghost = self._accumulate(lambda ids: np.broadcast_to(
            np.diag(Ke).reshape(8, 3), (len(ids), 8, 3)))

    def with_fixed(self, fixed):
        """The same product with the local DOFs ``fixed`` as identity rows and columns; it
        shares the element lists, scatter and vectors (the shells are applied in turn)."""
        other = copy.copy(self)
        other.fixed = np.asarray(fixed, np.int64)
        return other

    def _accumulate(self, element_values):
        """(3 n_ghost,) the sum over elements of element_values(ids) (k, 8, 3) at their nodes."""
        out = np.zeros((self.n_ghost, 3))
        for s in range(0, self.n_elements, self.CHUNK):
            ids = np.arange(s, min(self.n_elements, s + self.CHUNK))
            conn = self.conn[ids]
            lo, hi = int(conn.min()), int(conn.max()) + 1
            F = element_values(ids)
            if not self.uniform:
                F = F * self.weights[ids, None, None]
            flat = (conn - lo).ravel()
            for c in range(3):
                out[lo:hi, c] += np.bincount(flat, weights=F[:, :, c].ravel(), minlength=hi - lo)
        return out.ravel()

    def _apply(self, u):
        u3 = u.reshape(-1, 3)
        return self._accumulate(
            lambda ids: (u3[self.conn[ids]].reshape(len(ids), 24) @ self.Ke).reshape(-1, 8, 3))

    def mult(self, mat, x, y):
        src = x
        if self.fixed.size:   # only some ranks hold prescribed DOFs: nothing collective here
            src = self.work
            x.copy(src)
            src.getArray()[self.fixed] = 0.0
        self.scatter.scatter(src, self.ghost, PETSc.InsertMode.INSERT,
                             PETSc.ScatterMode.FORWARD)
        self.ghost_out.setArray(self._apply(self.ghost.getArray(readonly=True)))
        y.zeroEntries()
        self.scatter.scatter(self.ghost_out, y, PETSc.InsertMode.ADD,
                             PETSc.ScatterMode.REVERSE)
        if self.fixed.size:
            y.getArray()[self.fixed] = x.getArray(readonly=True)[self.fixed]

    def getDiagonal(self, mat, d):
        self.ghost_out.setArray(self.diag_ghost)
        d.zeroEntries()
        self.scatter.scatter(self.ghost_out, d, PETSc.InsertMode.ADD,
                             PETSc.ScatterMode.REVERSE)
        if self.fixed.size:
            d.getArray()[self.fixed] = 1.0

    def frobenius_bound(self):
        """An upper bound of ||K||_F (at most 8 elements share a node pair)."""
        mpi = self.comm.tompi4py()
        total = mpi.allreduce(float(np.sum(self.weights ** 2)))
        return float(np.sqrt(8.0 * total) * np.linalg.norm(self.Ke))


def shell(comm, product):
    """A PETSc shell matrix of block size 3 around an :class:`ElementProduct`."""
    n = product.n_local
    A = PETSc.Mat().createPython(((n, PETSc.DECIDE), (n, PETSc.DECIDE)), product, comm=comm)
    A.setBlockSize(3)
    A.setUp()
    return A


def two_grid(comm, mesh, Ke, h, r0, r1, fixed_nodes, grip):
    """(coarse operator Ac, interpolation P, coarse mesh) of the two-grid preconditioner.

    h (3,): the fine voxel sides (the unit of the coordinates); fixed_nodes: the fine
    prescribed active nodes (global, sorted; periodic: [0], node 0 pinned on both grids);
    grip: KUBC's gripped grid nodes, or None (the box's faces).
    """
    coarse = coarse_mesh(mesh)
    size, rank = comm.getSize(), comm.getRank()
    cb = row_ranges(coarse.n_nodes, size)
    c0, c1 = int(cb[rank]), int(cb[rank + 1])
    if mesh.periodic:
        c_fixed = np.array([0]) if c0 == 0 and c1 > 0 else np.zeros(0, np.int64)
    else:
        c_fixed = coarse.boundary_nodes(None if grip is None else coarse_grip(grip, coarse))
    indptr, cols, blocks = block_rows(coarse, 2.0 * Ke, c0, c1)   # Ke scales with the side
    csr = sp.bsr_matrix((blocks, cols, indptr), shape=(3 * (c1 - c0), 3 * coarse.n_nodes)).tocsr()
    it = PETSc.IntType
    Ac = PETSc.Mat().createAIJ(size=((3 * (c1 - c0), PETSc.DECIDE),) * 2, bsize=3,
                               csr=(csr.indptr.astype(it), csr.indices.astype(it), csr.data),
                               comm=comm)
    Ac.assemble()
    mine = c_fixed[(c_fixed >= c0) & (c_fixed < c1)]
    cdofs = (3 * mine[:, None] + np.arange(3)).ravel().astype(it)
    Ac.zeroRowsColumns(cdofs, diag=1.0)
    coords = Ac.createVecRight()
    coords.setBlockSize(3)
    coords.setArray((coarse.node_ijk(np.arange(c0, c1)) * (2.0 * np.asarray(h))).ravel())
    Ac.setNearNullSpace(PETSc.NullSpace().createRigidBody(coords))
    # interpolation: prescribed fine rows and coarse columns get no correction
    Ps = prolongation(mesh, coarse, r0, r1)
    keep_row = np.ones(r1 - r0)
    f_mine = fixed_nodes[(fixed_nodes >= r0) & (fixed_nodes < r1)] - r0
    keep_row[f_mine] = 0.0
    keep_col = np.ones(coarse.n_nodes)
    keep_col[c_fixed] = 0.0
    Ps = (sp.diags(keep_row) @ Ps @ sp.diags(keep_col)).tocsr()
    Ps.eliminate_zeros()
    P3 = sp.kron(Ps, sp.identity(3), format="csr")
    P3.sort_indices()
    P = PETSc.Mat().createAIJ(size=((3 * (r1 - r0), PETSc.DECIDE), (3 * (c1 - c0), PETSc.DECIDE)),
                              bsize=3, csr=(P3.indptr.astype(it), P3.indices.astype(it),
                                            P3.data), comm=comm)
    P.assemble()
    return Ac, P, coarse


def matrix_free_ksp(A, Ac, P, rtol, max_it):
    """CG preconditioned by the two-grid PCMG (fine: Chebyshev(2) + Jacobi on the shell A;
    coarse: one GAMG cycle on Ac); the PETSc options database overrides."""
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A, A)
    ksp.setType("cg")
    ksp.setTolerances(rtol=rtol, max_it=max_it)
    pc = ksp.getPC()
    pc.setType("mg")
    pc.setMGLevels(2)
    pc.setMGType(PETSc.PC.MGType.MULTIPLICATIVE)
    pc.setMGInterpolation(1, P)
    smoother = pc.getMGSmoother(1)
    smoother.setOperators(A, A)
    smoother.setType("chebyshev")
    smoother.getPC().setType("jacobi")
    smoother.setTolerances(max_it=2)
    coarse = pc.getMGCoarseSolve()
    coarse.setOperators(Ac, Ac)
    coarse.setType("preonly")
    coarse.getPC().setType("gamg")
    ksp.setFromOptions()
    return ksp

"""Distributed assembly of the frame's stiffness matrix (AIJ, block size 6).

Each rank owns a contiguous block of particles (rows) and builds only the
element blocks of bonds touching them; it then sets its rows in one call from
a block-CSR structure, so the matrix is preallocated exactly and no entry
crosses ranks. (PETSc 3.18's GAMG needs AIJ with block size 6: BAIJ fails in
MatCreateGraph.)

Memory traffic, not arithmetic, is what assembly costs (on this project's
virtual machines a page touched for the first time costs 3-5 s/GB;
docs/benchmarks.md, "Six right-hand sides at once"): the element blocks are
made :data:`CHUNK` bonds at a time straight into their rows, and each rank's
rows come split into the two parts MPIAIJ stores, so that no (bonds, 6, 6)
and no per-entry temporary is ever made.
"""
from contextlib import contextmanager

import numpy as np
import scipy.sparse as sp

from amfe.model.element import element_blocks
from amfe.solvers.petsclib import PETSc

CHUNK = 1 << 16
"""Bonds per call of element_blocks (three 19 MB blocks and its temporaries)."""


@contextmanager
def small_pages():
    """numpy's new arrays on ordinary 4 KiB pages inside the block.

    numpy asks Linux for transparent huge pages on every large array
    (madvise). Where the kernel must first compact memory to find 2 MiB pages,
    as on this project's virtual machines, touching such an array the first
    time costs 1.4-4.3 s/GB against 0.7-0.9 s/GB on small pages; once huge
    pages are at hand they are cheaper (0.16 s/GB) and the solves' gathers
    profit from them. The block rows (:func:`local_block_rows`, 0.53 GB a
    rank on the paper's bed, written once and freed before GAMG's set-up)
    take small pages: assembly 8-9.5 -> 6-7 s. The AIJ arrays, which every
    product streams through, keep huge pages: on small pages the six solves
    took 1.9 s longer (docs/benchmarks.md, "Huge pages").
    """
    setter = getattr(np.core.multiarray, "_set_madvise_hugepage", None)
    previous = setter(False) if setter is not None else None
    try:
        yield
    finally:
        if setter is not None:
            setter(previous)


def local_block_rows(frame, r0, r1):
    """Block CSR of rows [r0, r1) of the global stiffness: (indptr, cols, blocks).

    The rows come twice: first with the blocks whose columns lie in [r0, r1)
    (the rank's own particles: MPIAIJ's diagonal part), then with the others
    (its off-diagonal part), each sorted by (row, column). So indptr
    (2 nloc + 1,) is the block CSR of the stacked (2 nloc, n) block matrix
    [own columns; other columns] and ``indptr[nloc]`` where the second part
    starts; cols (nnzb,) global particle indices; blocks (nnzb, 6, 6).
    Units: those of ``frame`` (non-dimensional).
    """
    b = frame.bonds
    nloc = r1 - r0
    in_i, in_j = (b.i >= r0) & (b.i < r1), (b.j >= r0) & (b.j < r1)
    idx = np.flatnonzero(in_i | in_j)
    bi, bj = b.i[idx], b.j[idx]
    own_i, own_j = np.flatnonzero(in_i[idx]), np.flatnonzero(in_j[idx])
    del in_i, in_j
    rows = np.concatenate([np.arange(nloc), bi[own_i] - r0, bj[own_j] - r0])
    cols = np.concatenate([np.arange(r0, r1), bj[own_i], bi[own_j]])
    rows += nloc * ((cols < r0) | (cols >= r1))  # the row of the stacked matrix
    order = np.lexsort((cols, rows))
    slot = np.empty_like(order)  # where each source block goes: diagonal, K_ij, K_ij^T
    slot[order] = np.arange(order.size)
    cols = cols[order]
    del order
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=2 * nloc))])
    del rows
    blocks = np.empty((cols.size, 6, 6))
    diag = np.zeros((nloc, 36))
    slots = (slot[nloc:nloc + own_i.size], slot[nloc + own_i.size:])
    for s in range(0, idx.size, CHUNK):
        c = idx[s:s + CHUNK]
        Kii, Kij, Kjj = element_blocks(b.normal[c], b.d_i[c], b.d_j[c], frame.k_n[c],
                                       frame.k_t[c], frame.kappa_n[c], frame.kappa_t[c])
        for own, ends, K, to, flip in ((own_i, bi, Kii, slots[0], False),
                                       (own_j, bj, Kjj, slots[1], True)):
            lo, hi = np.searchsorted(own, [s, s + c.size])
            k = own[lo:hi] - s
            if k.size == 0:
                continue
            # K_ii (K_jj) summed into the diagonal blocks by an incidence product
            row = ends[s + k] - r0
            first = int(row.min())
            inc = sp.csr_matrix((np.ones(k.size), (row - first, k)),
                                shape=(int(row.max()) + 1 - first, c.size))
            diag[first:first + inc.shape[0]] += inc @ K.reshape(-1, 36)
            blocks[to[lo:hi]] = np.transpose(Kij[k], (0, 2, 1)) if flip else Kij[k]
    blocks[slot[:nloc]] = diag.reshape(nloc, 6, 6)
    return indptr, cols, blocks


def aij_from_blocks(comm, n, r0, r1, indptr, cols, blocks):
    """Rows [6 r0, 6 r1) of a (6n, 6n) AIJ matrix with block size 6, from block CSR.

    indptr, cols, blocks: as :func:`local_block_rows` gives them (the two
    parts). The matrix is made on arrays expanded from each part
    (MatCreate*AIJWithArrays: no copy, no per-row insertion; 1.9 s -> 0.03 s
    for 116k particles): MPIAIJ's diagonal part with local column numbers,
    its off-diagonal part with global ones. The arrays are kept alive as
    attributes of the matrix.
    """
    nloc = r1 - r0
    it = PETSc.IntType
    size = ((6 * nloc, 6 * n), (6 * nloc, 6 * n))
    mid = int(indptr[nloc])

    def scalar_csr(ptr, bcols, bvals, ncols):
        csr = sp.bsr_matrix((bvals, bcols, ptr), shape=(6 * nloc, 6 * ncols)).tocsr()
        return (np.asarray(csr.indptr, dtype=it), np.asarray(csr.indices, dtype=it), csr.data)

    local = scalar_csr(indptr[:nloc + 1], cols[:mid] - r0, blocks[:mid], nloc)
    if comm.getSize() == 1:
        arrays = local
    else:
        arrays = (local, scalar_csr(indptr[nloc:] - mid, cols[mid:], blocks[mid:], n))
    A = PETSc.Mat().createAIJWithArrays(size=size, csr=arrays, comm=comm)
    A.setAttr("amfe_csr_arrays", arrays)
    A.setBlockSize(6)
    A.setOption(PETSc.Mat.Option.NO_OFF_PROC_ENTRIES, True)
    A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    A.assemble()
    return A


def sbaij_operator(comm, n, r0, r1, indptr, cols, blocks, fixed):
    """The constrained operator as SBAIJ (upper 6x6 blocks), straight from block CSR.

    indptr, cols, blocks: as :func:`local_block_rows` gives them (the two parts).

    fixed (n,6) bool: prescribed DOFs; their rows and columns are zeroed except
    the diagonal entry, which keeps its value (as MatZeroRowsColumns followed
    by restoring the diagonal does to the AIJ matrix; MPISBAIJ has no
    MatZeroRowsColumns in PETSc 3.18, and converting AIJ costs seconds).
    """
    nloc = r1 - r0
    rows = np.repeat(np.tile(np.arange(r0, r1), 2), np.diff(indptr))  # the two parts
    up = np.flatnonzero(cols >= rows)
    up = up[np.argsort(rows[up], kind="stable")]  # by row: own columns, then the others
    rows, ucols, ublocks = rows[up], cols[up], blocks[up]
    on_diag = np.flatnonzero(rows == ucols)
    keep = np.diagonal(ublocks[on_diag], axis1=1, axis2=2).copy()
    ublocks *= ~fixed[rows][:, :, None]
    ublocks *= ~fixed[ucols][:, None, :]
    b, d = np.nonzero(fixed[rows[on_diag]])
    ublocks[on_diag[b], d, d] = keep[b, d]
    uptr = np.concatenate([[0], np.cumsum(np.bincount(rows - r0, minlength=nloc))])
    it = PETSc.IntType
    S = PETSc.Mat().createSBAIJ(size=((6 * nloc, 6 * n), (6 * nloc, 6 * n)), bsize=6,
                                csr=(uptr.astype(it), ucols.astype(it), ublocks.ravel()),
                                comm=comm)
    S.setOption(PETSc.Mat.Option.NO_OFF_PROC_ENTRIES, True)
    S.assemble()
    return S


def assemble_stiffness(frame, comm, r0, r1):
    """The global stiffness as a distributed PETSc AIJ matrix with block size 6.

    Rank owns particles [r0, r1), i.e. rows [6 r0, 6 r1).
    """
    return aij_from_blocks(comm, frame.n_particles, r0, r1, *local_block_rows(frame, r0, r1))

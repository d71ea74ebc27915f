"""Products of a PETSc matrix with a block of k columns, and the C calls petsc4py 3.18 lacks.

A block is a C-contiguous numpy array of shape (local rows, k): row i holds the
k columns' entries of row i. That is exactly the interleaved vector layout of
MatCreateMAIJ's M (x) I_k, so a block goes into PETSc by VecPlaceArray with no
copy, and one MatMult of the MAIJ matrix reads M once for all k columns.

Measured on a 46 800-particle bed (docs/benchmarks.md, section "Six right-hand
sides at once"): a 6-column MAIJ product with the fine AIJ matrix costs 1.3x one
AIJ MatMult; MatMatMult with a dense block costs 2x (its kernel takes 4 columns
per pass) and MPISBAIJ x dense falls back to one MatMult per column in 3.18.

petsc4py 3.18 wraps neither MatCreateMAIJ nor KSPChebyshevSetEigenvalues; both
are called through ctypes on the libpetsc this process has already loaded. If
that fails (no /proc/self/maps, 64-bit PetscInt), :func:`block_product` falls
back to MatMatMult / MatTransposeMatMult, which petsc4py does wrap.
"""
import ctypes
import re

import numpy as np

from amfe.errors import AmfeError
from amfe.solvers.petsclib import PETSc

_LIB = None


def petsc_library():
    """The ctypes handle of the libpetsc this process has loaded, or None."""
    global _LIB
    if _LIB is None:
        try:
            with open("/proc/self/maps") as f:
                paths = sorted(set(re.findall(r"(/\S*libpetsc[^/\s]*\.so[^/\s]*)", f.read())))
            lib = ctypes.CDLL(paths[0])
            lib.MatCreateMAIJ.argtypes = [ctypes.c_void_p, ctypes.c_int32,
                                          ctypes.POINTER(ctypes.c_void_p)]
            lib.MatMult.argtypes = [ctypes.c_void_p] * 3
            lib.MatMultTranspose.argtypes = [ctypes.c_void_p] * 3
            lib.MatDestroy.argtypes = [ctypes.POINTER(ctypes.c_void_p)]
            lib.KSPChebyshevSetEigenvalues.argtypes = [ctypes.c_void_p, ctypes.c_double,
                                                       ctypes.c_double]
            _LIB = lib
        except (OSError, IndexError, AttributeError):
            _LIB = False
    return _LIB or None


def set_chebyshev_targets(ksp, emin, emax):
    """KSPChebyshevSetEigenvalues(ksp, emax, emin): fix a Chebyshev KSP's target interval.

    It also turns the KSP's own eigenvalue estimation off (PETSc 3.18).
    Collective; emin, emax must be the same on every rank. Raises AmfeError
    if the C function cannot be reached or fails.
    """
    lib = petsc_library()
    if lib is None or lib.KSPChebyshevSetEigenvalues(ctypes.c_void_p(ksp.handle),
                                                     float(emax), float(emin)) != 0:
        raise AmfeError("KSPChebyshevSetEigenvalues is not reachable through ctypes")


class MaijProduct:
    """Y = (M (x) I_k) X: every column times M in one pass over M (MatCreateMAIJ).

    M: a (Seq|MPI)AIJ matrix of local size (m, n); X, Y: C-contiguous float64
    blocks (n, k) for :meth:`mult` and (m, k) for :meth:`mult_transpose`.
    """

    def __init__(self, M, k):
        lib = petsc_library()
        if lib is None or PETSc.IntType != np.int32:
            raise AmfeError("MatCreateMAIJ is not reachable through ctypes (32-bit PetscInt)")
        self.lib, self.k = lib, k
        self.ptr = ctypes.c_void_p()
        if lib.MatCreateMAIJ(ctypes.c_void_p(M.handle), k, ctypes.byref(self.ptr)) != 0:
            raise AmfeError(f"MatCreateMAIJ failed for a {M.getType()} matrix")
        (m, m_global), (n, n_global) = M.getSizes()
        comm = M.getComm()
        self._right = PETSc.Vec().createMPI((k * n, k * n_global), comm=comm)
        self._left = PETSc.Vec().createMPI((k * m, k * m_global), comm=comm)

    def _call(self, fn, X, Y, vin, vout):
        if not (X.flags.c_contiguous and Y.flags.c_contiguous):
            raise ValueError("blocks must be C-contiguous (rows, k) arrays")
        vin.placeArray(X.reshape(-1))
        vout.placeArray(Y.reshape(-1))
        try:
            err = fn(self.ptr, ctypes.c_void_p(vin.handle), ctypes.c_void_p(vout.handle))
        finally:
            vin.resetArray()
            vout.resetArray()
        if err:
            raise AmfeError(f"a MAIJ product failed with PETSc error {err}; its message is above")
        return Y

    def mult(self, X, Y):
        """Y = M X; returns Y."""
        return self._call(self.lib.MatMult, X, Y, self._right, self._left)

    def mult_transpose(self, X, Y):
        """Y = M^T X; returns Y."""
        return self._call(self.lib.MatMultTranspose, X, Y, self._left, self._right)

    def destroy(self):
        if self.ptr:
            self.lib.MatDestroy(ctypes.byref(self.ptr))
            self.ptr = ctypes.c_void_p()
        self._right.destroy()
        self._left.destroy()


class DenseProduct:
    """The same products by MatMatMult / MatTransposeMatMult with MATDENSE blocks.

    Pure petsc4py (the fallback): native for AIJ in 3.18, one copy in and out.
    """

    def __init__(self, M, k):
        (m, m_global), (n, n_global) = M.getSizes()
        comm = M.getComm()
        self.M = M
        self._right = PETSc.Mat().createDense(((n, n_global), (None, k)), comm=comm)
        self._left = PETSc.Mat().createDense(((m, m_global), (None, k)), comm=comm)
        for D in (self._right, self._left):
            D.setUp()
            D.assemble()
        self._y = self._yt = None

    def mult(self, X, Y):
        self._right.getDenseArray()[:] = X
        self._y = self.M.matMult(self._right, self._y)
        Y[:] = self._y.getDenseArray()
        return Y

    def mult_transpose(self, X, Y):
        self._left.getDenseArray()[:] = X
        self._yt = self.M.transposeMatMult(self._left, self._yt)
        Y[:] = self._yt.getDenseArray()
        return Y

    def destroy(self):
        for D in (self._right, self._left, self._y, self._yt):
            if D is not None:
                D.destroy()


def block_product(M, k, backend="auto"):
    """A k-column product object for M: ``.mult(X, Y)``, ``.mult_transpose(X, Y)``.

    backend: "maij" (fails unless MAIJ works), "dense", or "auto" (MAIJ for an
    AIJ matrix when reachable, else dense).
    """
    if backend not in ("auto", "maij", "dense"):
        raise AmfeError(f"unknown block product backend {backend!r}; choose auto, maij or dense")
    if backend != "dense" and M.getType() in ("seqaij", "mpiaij"):
        try:
            return MaijProduct(M, k)
        except AmfeError:
            if backend == "maij":
                raise
    elif backend == "maij":
        raise AmfeError(f"MAIJ needs an AIJ matrix, not {M.getType()}")
    return DenseProduct(M, k)

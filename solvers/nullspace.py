"""Near null space of a free frame of 6-DOF nodes: the six rigid-body modes."""
import numpy as np

from amfe.model.loadcase import rigid_body_modes
from amfe.solvers.petsclib import PETSc


def near_nullspace(A, local_points, center):
    """An orthonormal PETSc NullSpace of the six rigid-body modes on A's row layout.

    local_points (nloc,3): this rank's node coordinates (the rows A owns);
    center (3,): the same rotation centre on every rank (the global centroid,
    which keeps the modes well conditioned).
    """
    return orthonormal_nullspace(A, rigid_body_modes(local_points, center))


def orthonormal_nullspace(A, local_modes):
    """A PETSc NullSpace spanned by ``local_modes`` (m, nloc*6 or m, nloc, 6) on A's rows.

    Orthonormalised by modified Gram-Schmidt with global dot products.
    """
    vecs = []
    for m in local_modes:
        v = A.createVecRight()
        v.setArray(np.ravel(m))
        for w in vecs:
            v.axpy(-v.dot(w), w)
        v.normalize()
        vecs.append(v)
    return PETSc.NullSpace().create(vectors=vecs, comm=A.getComm())

"""Near null space of a free frame of 6-DOF nodes: the six rigid-body modes."""
import numpy as np


def rigid_body_modes(points, center=None):
    """(6, 6n) rigid-body modes of n nodes with DOFs (u_x, u_y, u_z, th_x, th_y, th_z).

    Modes 0-2 translate; modes 3-5 rotate about the axes through ``center``
    (default: the centroid of ``points`` (n,3)): a rotation omega moves u by
    omega x (x - center) AND sets theta = omega. (PETSc's
    MatNullSpaceCreateRigidBody covers 3-DOF nodes only.)
    """
    center = points.mean(axis=0) if center is None else np.asarray(center, float)
    rel = points - center
    modes = np.zeros((6, points.shape[0], 6))
    for a in range(3):
        omega = np.eye(3)[a]
        modes[a, :, a] = 1.0
        modes[3 + a, :, :3] = np.cross(omega, rel)
        modes[3 + a, :, 3 + a] = 1.0
    return modes.reshape(6, -1)


def near_nullspace(PETSc, A, local_points, center):
    """An orthonormal PETSc NullSpace of the six rigid-body modes on A's row layout.

    local_points (nloc,3): this rank's node coordinates (the rows A owns);
    center (3,): the same rotation centre on every rank (the global centroid,
    which keeps the modes well conditioned).
    """
    modes = rigid_body_modes(local_points, center)
    vecs = []
    for k in range(6):
        v = A.createVecRight()
        v.setArray(modes[k])
        for w in vecs:  # modified Gram-Schmidt with global dot products
            v.axpy(-v.dot(w), w)
        v.normalize()
        vecs.append(v)
    return PETSc.NullSpace().create(vectors=vecs, comm=A.getComm())

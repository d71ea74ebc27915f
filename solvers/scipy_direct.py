"""A serial scipy baseline for KUBC: SuperLU on the free DOFs, no PETSc.

Independent of amfe.solvers.assembly and amfe.model.kubc (global K scattered from full
12x12 element matrices, prescribed DOFs eliminated by partitioning, reactions
from the unreduced K), so it serves both as the benchmark's direct-solver
baseline and as the tests' reference.
"""
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from amfe.model.averages import (
    bagi_strain,
    bagi_stress,
    box_center,
    hull_of,
    stiffness,
    unit_strains,
    voigt,
    voigt_strain,
)
from amfe.model.element import element_matrices
from amfe.model.kubc import boundary_particles, kubc_displacements


def global_stiffness(frame):
    """The frame's (6n, 6n) stiffness as a scipy CSR matrix (non-dimensional)."""
    b = frame.bonds
    K12 = element_matrices(b.normal, b.d_i, b.d_j, frame.k_n, frame.k_t, frame.kappa_n,
                           frame.kappa_t)
    dofs = np.concatenate([6 * b.i[:, None] + np.arange(6), 6 * b.j[:, None] + np.arange(6)],
                          axis=1)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    n = 6 * frame.n_particles
    return sp.csr_matrix((K12.ravel(), (rows, cols)), shape=(n, n))


def kubc_stiffness_scipy(frame, strain="applied"):
    """(C (6,6) non-dimensional, seconds dict) of a frame under KUBC by SuperLU.

    strain="applied": the Voigt strains are the unit vectors, so C's columns
    are the Bagi stresses. strain="bagi": C = Sig Eps^-1 with Eps the Bagi
    strains of the solved displacements on the hull, as amfe.model.averages does;
    the two agree when every hull vertex is a prescribed boundary particle
    and differ when a hull vertex is not (a scan track ending short of a
    face), where "bagi" is the definition amfe's labels use.
    """
    t0 = time.perf_counter()
    K = global_stiffness(frame)
    x = frame.centers
    xc = box_center(x)
    bnd = np.flatnonzero(boundary_particles(x, frame.radii))
    pres = (6 * bnd[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(K.shape[0]), pres)
    Kff = K[free][:, free].tocsc()
    Kfp = K[free][:, pres]
    t1 = time.perf_counter()
    lu = spla.splu(Kff, permc_spec="MMD_AT_PLUS_A")  # symmetric pattern: a symmetric ordering
    t2 = time.perf_counter()
    U = np.zeros((K.shape[0], 6))
    for k, eps in enumerate(unit_strains()):
        U[pres, k] = kubc_displacements(x[bnd], xc, eps).ravel()
    U[free] = lu.solve(-(Kfp @ U[pres]))
    t3 = time.perf_counter()
    F = (K @ U)[pres]
    volume = frame.volume  # the bed's box (docs/model.md, section 5)
    C = np.array([voigt(bagi_stress(F[:, k].reshape(-1, 3), x[bnd], xc, volume))
                  for k in range(6)]).T
    if strain == "bagi":
        hull = hull_of(x)
        eps = [voigt_strain(bagi_strain(hull, U[:, k].reshape(-1, 6)[:, :3])) for k in range(6)]
        C = stiffness(np.array(eps), C.T)[0]
    elif strain != "applied":
        raise ValueError(f"strain must be 'applied' or 'bagi', got {strain!r}")
    return C, {"setup": t1 - t0, "factor": t2 - t1, "solve": t3 - t2}


def group_solve_scipy(frame, group):
    """SuperLU solution (c, n, 6) of a pinned, force-loaded group (SUBC, periodic).

    The fixed DOFs of ``group`` are held at zero (its values must be zero),
    the rest solve K U = F with F = group.forces; no PETSc. The tests'
    reference for the SUBC and periodic paths.
    """
    K = global_stiffness(frame)
    held = np.flatnonzero(group.fixed.ravel())
    free = np.setdiff1d(np.arange(K.shape[0]), held)
    F = np.asarray(group.forces).reshape(len(group.names), -1)
    U = np.zeros_like(F)
    lu = spla.splu(K[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A")
    U[:, free] = lu.solve(np.ascontiguousarray(F[:, free].T)).T
    return U.reshape(len(group.names), frame.n_particles, 6)

"""Shared test fixtures: small beds and an independent scipy reference solver."""
import os
import subprocess
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from amfe.element import element_matrices
from amfe.homogenize import bagi_stress, boundary_particles, box_center, hull_of, unit_strains, voigt

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")


def cubic_lattice(n, spacing=1.8e-6, radius=1e-6):
    """n x n x n simple cubic lattice: centres (n^3,3) [m], radii (n^3,) [m]."""
    g = np.arange(n) * spacing
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return x, np.full(len(x), radius)


def scipy_kubc_stiffness(frame):
    """C (6x6, non-dimensional) of a frame under KUBC by scipy's sparse direct solver.

    Independent of solvers/: global K scattered from full 12x12 element
    matrices, prescribed DOFs eliminated by partitioning, reactions K_bf u_f + K_bb u_b.
    """
    b = frame.bonds
    K12 = element_matrices(b.normal, b.d_i, b.d_j, frame.k_n, frame.k_t, frame.kappa_n, frame.kappa_t)
    dofs = np.concatenate([6 * b.i[:, None] + np.arange(6), 6 * b.j[:, None] + np.arange(6)], axis=1)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    n = 6 * frame.n_particles
    K = sp.csr_matrix((K12.ravel(), (rows, cols)), shape=(n, n))
    x = frame.centers
    xc = box_center(x)
    bnd = np.flatnonzero(boundary_particles(x, frame.radii))
    pres = (6 * bnd[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(n), pres)
    Kff = K[free][:, free].tocsc()
    lu = spla.splu(Kff)
    hull = hull_of(x)
    strains, stresses = [], []
    for k, eps in enumerate(unit_strains()):
        u = np.zeros(n)
        u[pres] = ((x[bnd] - xc) @ eps.T).ravel()
        u[free] = lu.solve(-(K[free][:, pres] @ u[pres]))
        f = (K @ u)[pres].reshape(-1, 3)
        sigma = bagi_stress(f, x[bnd], xc, hull.volume)
        stresses.append(voigt(sigma))
        strains.append(np.eye(6)[k])
    return np.array(stresses).T  # Eps = I: C = Sig


def run_cli(args, ranks=None, cwd=None, timeout=300):
    """Run `amfe ARGS` (under mpirun -n RANKS if given); returns CompletedProcess."""
    cmd = [sys.executable, "-m", "amfe.cli", *args]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd or ROOT, env=MPI_ENV,
                          timeout=timeout)

"""Shared test fixtures: small beds and an independent scipy reference solver."""
import os
import subprocess
import sys

import numpy as np

from amfe.solvers.scipy_direct import kubc_stiffness_scipy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")


def cubic_lattice(n, spacing=1.8e-6, radius=1e-6):
    """n x n x n simple cubic lattice: centres (n^3,3) [m], radii (n^3,) [m]."""
    g = np.arange(n) * spacing
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return x, np.full(len(x), radius)


def scipy_kubc_stiffness(frame):
    """C (6x6, non-dimensional) by scipy's SuperLU: see amfe.solvers.scipy_direct."""
    return kubc_stiffness_scipy(frame)[0]


def run_cli(args, ranks=None, cwd=None, timeout=300):
    """Run `amfe ARGS` (under mpirun -n RANKS if given); returns CompletedProcess."""
    cmd = [sys.executable, "-m", "amfe.cli", *args]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd or ROOT, env=MPI_ENV,
                          timeout=timeout)


def run_mpi_script(script, ranks=2, timeout=300):
    """Run a Python script under `mpirun -n RANKS` from the repository root; CompletedProcess."""
    return subprocess.run(["mpirun", "-n", str(ranks), sys.executable, str(script)],
                          capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=timeout)


def homogenize_arrays(centers, radii, material=None, *, comm=None, box=None, petsc_args=None,
                      size=None, **options):
    """:func:`amfe.solvers.driver.homogenize_bed` on arrays, its result as the JSON dict
    (plus "fields" when asked): the array-level call the tests made before 0.3.0.

    ``solver`` defaults to "gamg" (the old default); box: the periodic box; size (3,) [m]:
    the bed's recorded box (attrs "size", V of the averages). A bad bed or
    bad options become the ``input_error`` of the collective check, as in amfe.homogenize.
    """
    from amfe.errors import AmfeError
    from amfe.model.bed import Bed
    from amfe.model.options import SolveOptions
    from amfe.solvers.driver import homogenize_bed

    options.setdefault("solver", "gamg")
    bed, opts, error = (centers, radii), None, None
    try:
        opts = SolveOptions(material=material, petsc_args=petsc_args, **options)
        attrs = {} if box is None else {"periodic": box}
        bed = Bed(centers, radii, attrs if size is None else {**attrs, "size": size})
    except AmfeError as exc:
        error = exc
    result = homogenize_bed(bed, opts, comm, input_error=error)
    d = result.to_dict()
    if result.fields is not None:
        d["fields"] = result.fields
    return d


def brute_grip(mesh, geo, centers=None, radii=None):
    """KUBC's prescribed active nodes, brute force: every node against every grip sphere
    (centers (B, 3), radii (B,) [m]), or without spheres the nodes on the box's faces."""
    ijk = mesh.node_ijk(np.arange(mesh.n_nodes))
    if centers is None:
        return np.flatnonzero(np.any((ijk == 0) | (ijk == mesh.n), axis=1))
    x = geo.grid.lo + ijk * geo.grid.h
    d2 = ((x[:, None, :] - centers[None]) ** 2).sum(axis=2)
    return np.flatnonzero(np.any(d2 <= radii ** 2, axis=1))

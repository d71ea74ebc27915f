"""Example 3: the same solve on several MPI ranks.

Run it as ``mpirun -n 2 python examples/03_mpi.py BED.h5`` (as root, Open MPI
also needs OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1). Without
an argument it generates a small bed on rank 0 first.
"""
import sys

from mpi4py import MPI

import amfe

comm = MPI.COMM_WORLD

# %% 1. A bed file. Only rank 0 writes; the others wait for it.
path = sys.argv[1] if len(sys.argv) > 1 else "results/example3_bed.h5"
if len(sys.argv) == 1 and comm.rank == 0:
    amfe.write_bed(path, amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=3))
comm.Barrier()

# %% 2. Pass the path: rank 0 reads it and broadcasts the bed, so every rank
# works on the same particles; each rank owns a block of the matrix rows.
result = amfe.homogenize(path, comm=comm, rtol=1e-10)

# %% 3. Every rank holds the same result; rank 0 reports it.
if comm.rank == 0:
    print(f"{comm.size} rank(s): Ex = {result.Ex / 1e9:.4f} GPa, "
          f"iterations {result.solver['iterations']}")

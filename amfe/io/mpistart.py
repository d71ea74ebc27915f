"""Open MPI's start on one host: ob1 over shared memory unless the user chose a transport.

Open MPI 4.1 (Debian 12's) picks its UCX layer by default, and UCX probes every
network device at MPI_Init; ob1 then opens every transport it has. On the build
machine that is 0.3 s of a rank's start (``mpirun -n 2 python -c "import numpy,
mpi4py.MPI"``: 0.46-0.47 s by default, 0.25-0.27 s with ob1; ``import amfe,
mpi4py.MPI``: 0.16 s with ob1 over self and vader; a single process: 0.30 s against
0.12 s with ob1). On one host the ranks talk through shared memory
either way (UCX's, or ob1's vader), so :func:`prefer_ob1_on_one_host` asks for ob1
with the self and vader transports alone there, before mpi4py starts MPI. The
transports are named too because ob1 would otherwise try the openib one on a host
with InfiniBand, which Open MPI 4 refuses with a warning on every run ("infiniband
ports on a device are not used by default"; open-mpi/ompi#10693). It sets nothing
when the user chose a layer or transports (``OMPI_MCA_pml``, ``OMPI_MCA_btl``, which
``mpirun --mca pml ucx`` and ``--mca btl ...`` set too), when the ranks span
hosts (``OMPI_COMM_WORLD_LOCAL_SIZE`` below ``OMPI_COMM_WORLD_SIZE``: there UCX's
network transports matter), or under another launcher (srun's PMI, MPICH's
``PMI_RANK``), which leaves the choice to Open MPI (docs/benchmarks.md, "Parameter sweeps").
"""
import os

#: Variables that another launcher than Open MPI's mpirun sets: a rank of a job whose hosts
#: amfe cannot count from the environment.
_OTHER_LAUNCHERS = ("PMIX_RANK", "PMI_RANK", "PMI_SIZE", "SLURM_PROCID", "HYDRA_CONTROL_FD")


def prefer_ob1_on_one_host(environ=None):
    """Set ``OMPI_MCA_pml=ob1`` and ``OMPI_MCA_btl=self,vader`` in ``environ`` (default
    os.environ) where every rank of the job is on this host and neither was chosen; True when
    it did. Call before mpi4py's import."""
    env = os.environ if environ is None else environ
    if "OMPI_MCA_pml" in env or "OMPI_MCA_btl" in env:
        return False
    size, local = env.get("OMPI_COMM_WORLD_SIZE"), env.get("OMPI_COMM_WORLD_LOCAL_SIZE")
    if size is None:   # not started by Open MPI's mpirun: a single process, or another launcher
        one_host = not any(name in env for name in _OTHER_LAUNCHERS)
    else:
        one_host = local is not None and local == size
    if one_host:
        env["OMPI_MCA_pml"], env["OMPI_MCA_btl"] = "ob1", "self,vader"
    return one_host

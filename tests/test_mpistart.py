"""amfe.io.mpistart: Open MPI's ob1 layer asked for where every rank is on this host."""
import subprocess
import sys

import pytest
from helpers import MPI_ENV, ROOT

from amfe.io.mpistart import prefer_ob1_on_one_host


@pytest.mark.parametrize("env, chosen", [
    ({}, True),                                                           # one process
    ({"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}, True),
    ({"OMPI_COMM_WORLD_SIZE": "4", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}, False),   # two hosts
    ({"OMPI_COMM_WORLD_SIZE": "4"}, False),
    ({"SLURM_PROCID": "0"}, False),                                      # srun: can't count
    ({"PMI_RANK": "0"}, False),                                          # MPICH's hydra
])
def test_ob1_only_on_one_host(env, chosen):
    env = dict(env)
    assert prefer_ob1_on_one_host(env) is chosen
    assert env.get("OMPI_MCA_pml") == ("ob1" if chosen else None)
    assert env.get("OMPI_MCA_btl") == ("self,vader" if chosen else None)


@pytest.mark.parametrize("given", [{"OMPI_MCA_pml": "ucx"}, {"OMPI_MCA_btl": "tcp,self"}])
def test_the_users_choice_stands(given):
    env = {**given, "OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}
    assert prefer_ob1_on_one_host(env) is False
    assert env == {**given, "OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}


@pytest.mark.mpi
def test_ranks_on_one_host_start_with_ob1_and_talk():
    """Under mpirun -n 3 on this host (oversubscribed), `import amfe` asks for ob1 over
    shared memory before MPI starts, and the ranks still exchange data (an allreduce)."""
    # one write a rank, newline included: print's pieces (and its newline, written apart on
    # an unbuffered stdout) could interleave between the ranks
    code = ("import os, sys, amfe; from mpi4py import MPI; "
            "sys.stdout.write(' '.join([os.environ['OMPI_MCA_pml'], os.environ['OMPI_MCA_btl'], "
            "str(MPI.COMM_WORLD.allreduce(MPI.COMM_WORLD.rank))]) + chr(10)); sys.stdout.flush()")
    proc = subprocess.run(["mpirun", "-n", "3", sys.executable, "-c", code], cwd=ROOT,
                          env={k: v for k, v in MPI_ENV.items()
                               if k not in ("OMPI_MCA_pml", "OMPI_MCA_btl")},
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[:3] == ["ob1 self,vader 3"] * 3

"""Parameter studies: :func:`sweep` makes beds over a grid of scan parameters and seeds, solves
or predicts each, and tabulates the constants with their spread over the seeds.

spec (:mod:`amfe.study.spec`) -> run, kill-safe and resumable (:mod:`amfe.study.run`) ->
tables (:mod:`amfe.study.table`) -> plot (:mod:`amfe.study.plot`). The command line is
``amfe sweep`` (amfe.cli.sweep).
"""
import os
import shutil
import tempfile

from amfe.study.run import run_sweep
from amfe.study.spec import SweepSpec, grid, seeds_of
from amfe.study.table import SweepTable, tables, write_tables


def sweep(grid_axes: dict, seeds: "int | list" = 4, *,
          size: tuple[float, float, float] = (0.6e-3, 0.6e-3, 0.3e-3),
          method: str = "solver", fallback: bool = False, solver: str = "auto",
          rtol: float | None = None, output: str | os.PathLike | None = None,
          comm: object = None,
          base: dict | None = None, progress: bool = False,
          springs: str = "paper", flag_share: float | None = None) -> SweepTable:
    """The constants of beds over the full grid of ``grid_axes`` {parameter: [values]} (SI:
    lengths in m) times ``seeds`` (a count, 0..N-1, or a list), as a :class:`SweepTable`.

    size (3,) [m]: the beds' box; method "solver" or "surrogate" (``fallback``: flagged
    beds solved); ``output``: a directory to keep the rows and tables in (a rerun resumes
    it); None: a temporary one; springs: "paper" or "continuum" (as ``amfe.homogenize``;
    with the surrogate, the continuum springs' model); flag_share: the surrogate's flagged
    share (as ``amfe predict --flag-share``). Under mpirun every rank calls it;
    each solves its share of the beds (one rank a bed) and every rank gets the table.
    """
    spec = SweepSpec(points=grid(list(grid_axes.items())), seeds=seeds_of(seeds),
                     size=tuple(float(s) for s in size), method=method, fallback=fallback,
                     solver=solver, rtol=rtol, base=dict(base or {}), springs=springs,
                     flag_share=flag_share)
    from mpi4py import MPI
    world = comm if comm is not None else MPI.COMM_WORLD
    if output is None:   # rank 0's temporary directory, shared by the ranks of one host
        tmp = world.bcast(tempfile.mkdtemp(prefix="amfe-sweep-") if world.rank == 0 else None)
        try:
            rows = run_sweep(spec, tmp, comm=world, progress=progress)
        finally:
            world.Barrier()
            if world.rank == 0:
                shutil.rmtree(tmp, ignore_errors=True)
    else:
        rows = run_sweep(spec, output, comm=world, progress=progress)
    table = tables(rows, spec.to_dict())
    if output is not None and world.rank == 0:
        write_tables(table, output)
    return table

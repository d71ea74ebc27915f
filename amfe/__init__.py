"""amfe: powder beds of sintered spheres as bonded space frames.

The flow is bed -> frame -> solve -> average -> properties:

>>> import amfe
>>> bed = amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)   # metres
>>> result = amfe.homogenize(bed)
>>> f"{result.Ex / 1e9:.0f} GPa"
'90 GPa'

The face (imported lazily: ``import amfe`` pulls in neither PETSc nor torch):

- :class:`Bed`, :func:`generate_bed`, :class:`ScanPath`, :class:`Material`,
  ``STEEL``: beds and how they are made (:mod:`amfe.model`).
- :func:`read_bed`, :func:`write_bed`: bed files (:mod:`amfe.io`).
- :func:`read_result`: a result JSON read back (a :class:`Result`, a
  :class:`ResultSet` of ``--bc all``, or ``predict``'s predictions).
- :func:`homogenize` -> :class:`Result` (with :class:`Fields`): the PETSc
  solve of the six load cases and the Bagi averages; :func:`homogenize_bed`
  is the function under it (:mod:`amfe.solvers`). Changed in 0.3.0:
  ``homogenize_bed(bed, options, comm=None)`` takes a checked :class:`Bed` and
  one :class:`SolveOptions` and returns a :class:`Result` (it took arrays and
  keyword options and returned a dict).
- :func:`predict` -> :class:`Prediction` (or a list): the surrogate's constants of beds,
  the shipped model picked by each bed's size and material as ``amfe predict`` does, with
  intervals and flag; :class:`Surrogate`: the CNN under it, on image arrays
  (:mod:`amfe.training`).
- :class:`AmfeError`: every error meant for a user.

Under mpirun, an exception that no one catches on one rank of a script ends every
rank (MPI_Abort after the traceback; :func:`amfe.io.mpi.abort_on_uncaught`) instead of
leaving the others waiting in amfe's next collective.

Layers, bottom to top (README, Layout): amfe.errors/vocab, amfe.model,
amfe.io, amfe.solvers, amfe.dataset, amfe.training, then this face and
amfe.cli. docs/model.md holds the physics and the conventions.
"""
import importlib

from amfe.io.mpi import abort_on_uncaught
from amfe.io.mpistart import prefer_ob1_on_one_host
from amfe.version import __version__

prefer_ob1_on_one_host()   # before any mpi4py import: MPI starts 0.3 s sooner on one host
abort_on_uncaught()   # under mpirun, an uncaught exception on one rank ends every rank

_FACE = {
    "Bed": "amfe.model.bed", "generate_bed": "amfe.model.bed",
    "ScanPath": "amfe.model.scanpath", "Material": "amfe.model.material",
    "STEEL": "amfe.model.material",
    "read_bed": "amfe.io.bedfile", "write_bed": "amfe.io.bedfile",
    "homogenize": "amfe.api", "Result": "amfe.io.result", "Fields": "amfe.io.result",
    "read_result": "amfe.io.readback", "ResultSet": "amfe.io.readback",
    "sweep": "amfe.study", "SweepTable": "amfe.study.table",
    "homogenize_bed": "amfe.solvers.driver", "SolveOptions": "amfe.model.options",
    "Surrogate": "amfe.training.predict", "predict": "amfe.predicting",
    "Prediction": "amfe.training.prediction",
    "AmfeError": "amfe.errors",
}

__all__ = sorted(_FACE) + ["__version__"]


def __getattr__(name):
    if name in _FACE:
        value = getattr(importlib.import_module(_FACE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'amfe' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_FACE))

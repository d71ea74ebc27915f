"""amfe: powder beds of sintered spheres as bonded space frames.

The flow is bed -> bonds -> element -> frame -> solve -> homogenize -> properties:

- :mod:`amfe.bed`, :mod:`amfe.scanpath`: powder-bed generator (HCP + raster scan).
- :mod:`amfe.bonds`, :mod:`amfe.springs`, :mod:`amfe.element`: the bonded frame.
- :mod:`amfe.frame`: the load-carrying part of a bed, non-dimensionalised.
- :mod:`solvers`: the distributed PETSc matrix and the six load cases.
- :mod:`amfe.homogenize`: Bagi volume averages, C, S and the elastic constants.
"""
__version__ = "0.1.0"

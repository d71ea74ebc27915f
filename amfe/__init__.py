"""amfe: powder beds of sintered spheres as bonded space frames.

The flow is bed -> bonds -> element -> frame -> solve -> homogenize -> properties:

- :mod:`amfe.bed`, :mod:`amfe.scanpath`: powder-bed generator (HCP + raster scan).
- :mod:`amfe.bonds`, :mod:`amfe.springs`, :mod:`amfe.element`: the bonded frame.
- :mod:`amfe.frame`: the load-carrying part of a bed, non-dimensionalised.
- :mod:`solvers`: the distributed PETSc matrix and the six load cases.
- :mod:`amfe.homogenize`: Bagi volume averages, C, S and the elastic constants.
"""
__version__ = "0.1.0"

from .bed import Bed, generate_bed  # noqa: E402
from .bedio import read_bed, write_bed  # noqa: E402
from .material import STEEL, Material  # noqa: E402
from .scanpath import ScanPath  # noqa: E402


def __getattr__(name):
    # PETSc is imported only when a solve is asked for.
    if name == "homogenize_bed":
        from solvers.driver import homogenize_bed
        return homogenize_bed
    raise AttributeError(f"module 'amfe' has no attribute {name!r}")


__all__ = ["Bed", "generate_bed", "read_bed", "write_bed", "Material", "STEEL", "ScanPath",
           "homogenize_bed"]

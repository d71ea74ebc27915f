"""Compiled (numba) imaging: pixelate_spheres' union volumes, bit for bit its numpy path.

The numpy path of amfe.dataset.images generates every (sphere, sample line)
chord as array elements and sorts them all by one int64 key (6 s for a
3 x 3 x 0.3 mm bed of 260 000 particles, most of it in the sort and the
temporaries). This kernel does the same arithmetic one chord at a time:

* per strip of sample rows (the numpy path's strips, so the sums run in its
  order), each sphere's chords are found row by row, scanning out from the
  sample column nearest its centre while (R^2 - dx^2) - dy^2 > 0 (the
  covered set of a row is one run of columns, since dx^2 grows away from the
  centre), cut at the layer faces and quantised exactly as the numpy path;
* a counting sort by (layer, sample line) replaces the global sort, and each
  line's few chords are sorted by (start, end) in place, so the union's
  running maximum and the float sum of covered lengths follow the numpy
  path's sorted order;
* a line's volume goes into the strip's pixel sums in the order of
  np.bincount over (layer, row, column), and each strip is added to the image
  as the numpy path adds it.

Every float operation is the numpy path's, in its order, so the images are
identical bit for bit (tests/test_pixelkernel.py); it is the same imaging
(IMAGING_VERSION unchanged). numba is imported only when a caller asks for
this kernel (:func:`available`).
"""
import sys

import numpy as np

from amfe.errors import AmfeError

_AVAILABLE = None


def available():
    """True when numba imports (the kernel can run); asked once per process."""
    global _AVAILABLE
    if _AVAILABLE is None:
        try:
            import numba  # noqa: F401
            _AVAILABLE = True
        except ImportError:
            _AVAILABLE = False
    return _AVAILABLE


def _loaded():
    return "amfe.dataset._jit" in sys.modules


def warm():
    """Load the compiled kernels now (about 0.3 s from numba's cache), where numba imports, so
    that "auto" takes them for every later bed, small ones too, and amfe.model.bonds.find_pairs
    finds bonds with them: for a process that makes and images many beds. True when loaded."""
    if available():
        import amfe.dataset._jit  # noqa: F401  (compiled once, cached)
        import amfe.model._jit_pairs  # noqa: F401  (find_pairs takes it once loaded)
    return _loaded()


def use_kernel(engine, large):
    """Whether pixelate_spheres images with this kernel (the same bits as its numpy path).

    engine: "numpy", "compiled" (AmfeError without numba) or "auto": the kernel
    when numba imports and the bed is ``large`` (there it beats numba's import
    and cache load, about 0.5 s) or the kernel is loaded already (:func:`warm`:
    a small bed then images 10x faster, 0.011 s against 0.11 s at 0.6 mm).
    """
    if engine not in ("auto", "numpy", "compiled"):
        raise AmfeError(f"engine must be 'auto', 'numpy' or 'compiled', got {engine!r}")
    if engine == "numpy" or (engine == "auto" and not large and not _loaded()):
        return False
    if engine == "compiled" and not available():
        raise AmfeError("engine 'compiled' needs numba (pip install numba)")
    return available()


def union_volumes(c, r, grid, rows, q_levels, image):
    """Add the union volume [m^3] of spheres c (C,3) [m], r (C,) [m] in every cell to image.

    image: (layers*H*W,) float64, flat as in amfe.dataset.images; grid: its
    _Strip of all sample rows (sample grids, layer faces, the box in z);
    rows: sample rows per strip (the numpy path's); q_levels: quantisation
    levels per layer (its _Q_LEVELS).
    """
    from amfe.dataset._jit import union_rows  # imports numba (compiled once, cached)
    order = np.argsort(c[:, 1], kind="stable")
    c, r = np.ascontiguousarray(c[order]), np.ascontiguousarray(r[order])
    ax, ay, t = grid.ax, grid.ay, float(grid.t)
    z = (np.ascontiguousarray(grid.z_edges, np.float64), t, float(grid.z_lo), float(grid.z_hi),
         float(q_levels / t), float(t / q_levels))
    union_rows(c, r, (ax.mid, ax.w, ax.cell_of, float(ax.h)), (ay.mid, ay.w, ay.cell_of), z,
               (int(rows), int(ay.n_cells), int(ax.n_cells)), image)

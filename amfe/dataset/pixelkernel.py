"""Compiled imaging: pixelate_spheres' union volumes, bit for bit its numpy path.

The numpy path of amfe.dataset.images generates every (sphere, sample line)
chord as array elements and sorts them all by one int64 key (6 s for a
3 x 3 x 0.3 mm bed of 260 000 particles, most of it in the sort and the
temporaries). The compiled kernels do the same arithmetic one chord at a time
(amfe/dataset/fill.c, and its numba twin amfe.dataset._jit for a machine without
a C compiler):

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
(IMAGING_VERSION unchanged). The C kernel (amfe.model.native: built once per
machine, loaded in about a millisecond) takes every bed where it builds; numba
is imported only where it does not, or for the bond image's springs of a large
bed (amfe.dataset.bondimage).
"""
import ctypes
import sys
from functools import cache
from pathlib import Path

import numpy as np

from amfe.errors import AmfeError
from amfe.model.native import F64, I64, function

_AVAILABLE = None


def available():
    """True when a compiled union kernel can run: the C one builds, or numba imports."""
    return _c_fill() is not None or _numba()


def _numba():
    """True when numba imports (its kernels can run); asked once per process."""
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
    """Load the compiled kernels now, so that "auto" takes them for every later bed, small ones
    too: for a process that makes and images many beds. With the C kernel (it needs no start)
    nothing is loaded; else numba's (about 0.3 s from its cache). True when a kernel runs."""
    if _c_fill() is not None:
        return True
    if _numba():
        import amfe.dataset._jit  # noqa: F401  (compiled once, cached)
    return _loaded()


@cache
def _c_fill():
    """The C union kernel (amfe/dataset/fill.c), or None where it does not build."""
    i64, f64 = ctypes.c_int64, ctypes.c_double
    return function(Path(__file__).with_name("fill.c"), "amfe_union_rows", ctypes.c_int,
                    [i64, F64, F64, i64, F64, F64, I64, f64, i64, F64, F64, I64, f64,
                     i64, F64, f64, f64, f64, f64, f64, i64, i64, i64, F64])


def _check_engine(engine):
    if engine not in ("auto", "numpy", "compiled"):
        raise AmfeError(f"engine must be 'auto', 'numpy' or 'compiled', got {engine!r}")


def use_kernel(engine, large):
    """Whether pixelate_spheres images with a compiled kernel (the same bits as its numpy path).

    engine: "numpy", "compiled" (AmfeError without a C compiler or numba) or "auto": the
    C kernel where it builds; else numba's when it imports and the bed is ``large`` (there
    it beats numba's import and cache load, about 0.5 s) or it is loaded already
    (:func:`warm`: a small bed then images 10x faster, 0.011 s against 0.11 s at 0.6 mm).
    """
    _check_engine(engine)
    if engine == "numpy":
        return False
    if _c_fill() is not None:
        return True
    if engine == "auto" and not large and not _loaded():
        return False
    if engine == "compiled" and not _numba():
        raise AmfeError("engine 'compiled' needs a C compiler (cc; run/setup.sh installs gcc) "
                        "or numba (pip install numba)")
    return _numba()


def use_numba(engine, large):
    """Whether the bond image sums its springs with numba (amfe.dataset._jit.bond_sums_for):
    numba's rule of :func:`use_kernel` (a large bed, or numba loaded already), C aside."""
    _check_engine(engine)
    if engine == "numpy" or not (engine == "compiled" or large or _loaded()):
        return False
    return _numba()


def union_volumes(c, r, grid, rows, q_levels, image):
    """Add the union volume [m^3] of spheres c (C,3) [m], r (C,) [m] in every cell to image.

    image: (layers*H*W,) float64, flat as in amfe.dataset.images; grid: its
    _Strip of all sample rows (sample grids, layer faces, the box in z);
    rows: sample rows per strip (the numpy path's); q_levels: quantisation
    levels per layer (its _Q_LEVELS).
    """
    ax, ay, t = grid.ax, grid.ay, float(grid.t)
    z_edges = np.ascontiguousarray(grid.z_edges, np.float64)
    z = (z_edges, t, float(grid.z_lo), float(grid.z_hi), float(q_levels / t),
         float(t / q_levels))
    fn = _c_fill()
    if fn is not None:   # buckets the spheres by row itself (fill.c)
        c, r = np.ascontiguousarray(c, np.float64), np.ascontiguousarray(r, np.float64)
        xs = [np.ascontiguousarray(v) for v in (ax.mid, ax.w, ax.cell_of.astype(np.int64))]
        ys = [np.ascontiguousarray(v) for v in (ay.mid, ay.w, ay.cell_of.astype(np.int64))]
        status = fn(r.size, c, r, xs[0].size, *xs, float(ax.h), ys[0].size, *ys, float(ay.h),
                    z_edges.size - 1, *z, int(rows), int(ay.n_cells), int(ax.n_cells), image)
        if status != 0:
            raise MemoryError("the imaging kernel ran out of memory")
        return
    order = np.argsort(c[:, 1], kind="stable")
    c, r = np.ascontiguousarray(c[order]), np.ascontiguousarray(r[order])
    from amfe.dataset._jit import union_rows  # imports numba (compiled once, cached)
    union_rows(c, r, (ax.mid, ax.w, ax.cell_of, float(ax.h)), (ay.mid, ay.w, ay.cell_of), z,
               (int(rows), int(ay.n_cells), int(ax.n_cells)), image)

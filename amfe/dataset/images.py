"""Pixelated images of a powder bed: volume fractions of cuboid cells (docs/model.md, section 7).

Paper section 6: the bed is cut into cuboid cells of cell_x x cell_y in the
plane and one powder layer in height (default 0.03 mm x 0.03 mm x 0.1 mm);
each pixel is the fraction of its cell's volume filled by particles, 0 for
an empty cell and 1 for a full one. A 3 mm x 3 mm x 0.3 mm bed is a
3 x 100 x 100 image (layers, rows, columns).

The particles of a sintered bed overlap at their necks, so the filled region
is the UNION of the spheres; summing sphere volumes would count every lens
twice (5-10 % too much in a generated bed). The union is measured as follows:

* In the plane, every cell is sampled on a regular grid of nx x ny points,
  the centres of sub-rectangles of about ``spacing`` (default: the median
  radius / 6) that tile the cell exactly.
* Along the vertical line through each sample point the union is exact: each
  sphere it crosses gives the chord [z_c - sqrt(R^2 - rho^2), z_c + sqrt(...)];
  the chords are cut at the layer faces and merged per (layer, sample line)
  by sorting them by their lower end and keeping a running maximum of the
  upper ends, so overlaps are counted once.
* A cell's filled volume is the sum over its sample lines of (covered
  length x sub-rectangle area); the pixel is that over the cell volume.

Only the in-plane sampling approximates: the covered length is a continuous
function of (x, y) (a chord shrinks to 0 at a sphere's rim), so the midpoint
rule converges fast and, unlike a smoothed (anti-aliased) 3D raster of the
union, has no systematic error at the necks. Measured (tests/test_images.py,
run/bench/images.py --check), in units of a cell volume, at the default
spacing (median radius / 6): generated beds, against a 4x finer sampling,
rms 0.1 %, worst pixel 0.4 %; a single sphere inside a cell, worst of 300
random ones, 0.08 %; cells of whole HCP lattice periods, 0.003 %; a whole
generated bed against sum(spheres) - sum(lenses), 1e-4 relative.

All work is vectorised: the chord candidates of a chunk of spheres come from
a block of sample lines around each centre, and the plane is processed in
strips of sample rows sized so that a strip holds about ``_TILE_CHORDS``
chords (about 200 MB at most for a 3 x 3 x 0.3 mm bed), whatever the size
of the bed. Cost: about 120 chords per sphere at the default spacing, 5 s for
300 000 particles on one core; amfe.dataset.pixelkernel's C kernel gives the same
image bit for bit about 12x faster (engine "auto" takes it wherever it builds)."""
import math
from dataclasses import dataclass

import numpy as np

from amfe.dataset.pixelkernel import union_volumes, use_kernel
from amfe.errors import AmfeError
from amfe.model.bonds import validate_particles

DEFAULT_CELL = (30e-6, 30e-6)      # paper section 6: 0.03 mm x 0.03 mm in the plane [m]
DEFAULT_LAYER_THICKNESS = 100e-6   # one powder layer, 0.1 mm [m]
SAMPLES_PER_RADIUS = 6             # default in-plane sample spacing = median radius / 6
_TILE_CHORDS = 1_000_000           # chords per strip: bounds the temporaries (~100 B each)
_CHUNK_CANDIDATES = 2_000_000      # sphere x sample-offset candidates per chunk
_MAX_GROUPS = 4_000_000            # (layer, sample line) groups per strip (their tables)
_KERNEL_FROM = 2_000_000           # chords from which "auto" takes the compiled kernel
_Q_BITS = 17                       # bits of a chord end in the sort key ...
_Q_LEVELS = 1 << 16                # ... measured in units of layer thickness / 2^16
# A box within this relative tolerance of a whole number of cells (or layers)
# gets no sliver cell from round-off (0.25 mm / 0.05 mm is 5 cells, not 6).
_DIVIDE_TOL = 1e-9
#: The version of a data set's images (this module's pixelate and amfe.dataset.bondimage):
#: bump it when either gives other numbers for the same bed. Label tables record it, and
#: `amfe dataset --from-labels` refuses a table of another imaging (its images would differ
#: from those of the data set it came from).
IMAGING_VERSION = 1


def _positive(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise AmfeError(f"{name} must be a positive length in m, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise AmfeError(f"{name} must be a positive finite length in m, got {value!r}")
    return v


def _check_cell(cell):
    try:
        cx, cy = cell
    except (TypeError, ValueError):
        raise AmfeError(f"cell must be two lengths (cell_x, cell_y) in m, got {cell!r}") from None
    return _positive("cell_x", cx), _positive("cell_y", cy)


def _check_box(lo, hi):
    try:
        lo = np.array(lo, dtype=float).reshape(3)
        hi = np.array(hi, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise AmfeError(f"box must be two points lo, hi of three coordinates in m, "
                        f"got lo={lo!r}, hi={hi!r}") from None
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise AmfeError(f"box corners must be finite, got lo={lo.tolist()}, hi={hi.tolist()}")
    if not (hi > lo).all():
        raise AmfeError(f"box must have hi > lo on every axis, got lo={lo.tolist()} m, "
                        f"hi={hi.tolist()} m")
    return lo, hi


class _Axis:
    """Sample points along one in-plane axis of the box [lo, hi].

    Cells of width ``cell`` from lo, each split into ``n`` equal sub-intervals
    of width h = cell / n; the last sub-interval and cell are cut at hi.
    Attributes: h, n_sub, mid (n_sub,) sample positions (midpoints of the
    sub-intervals, clipped at hi) [m], w (n_sub,) their widths [m], cell_of
    (n_sub,) cell index of each sample, n_cells, cell_w (n_cells,) cell widths
    inside the box [m].
    """

    def __init__(self, lo, hi, cell, n):
        self.lo, self.h = lo, cell / n
        length = hi - lo
        self.n_sub = max(1, math.ceil(length / self.h - n * _DIVIDE_TOL))
        edges = lo + np.arange(self.n_sub + 1) * self.h
        edges[-1] = hi
        self.mid = 0.5 * (edges[:-1] + edges[1:])
        self.w = np.diff(edges)
        self.cell_of = np.arange(self.n_sub) // n
        self.n_cells = int(self.cell_of[-1]) + 1
        self.cell_w = np.bincount(self.cell_of, weights=self.w, minlength=self.n_cells)


def _layer_edges(lo, hi, t):
    """(layers + 1,) layer faces from lo up [m]; the top layer is cut at hi."""
    n = max(1, math.ceil((hi - lo) / t - _DIVIDE_TOL))
    edges = lo + np.arange(n + 1) * t
    edges[-1] = hi
    return edges


def _reach(r_max, h):
    """Half-width k of the run of sample offsets a sphere of radius <= r_max reaches on an axis.

    A centre lies in sub-interval b; the sample of sub-interval b + o is at
    least (|o| - 1) h away, so |o| <= ceil(r_max / h) + 1 holds every sample
    the sphere covers.
    """
    return math.ceil(r_max / h) + 1


@dataclass(frozen=True)
class _Strip:
    """One strip of sample rows [row0, row1) of the sample grid (ax, ay) and the box's
    layers: z_edges (layers+1,) [m] of thickness t [m], the box from z_lo to z_hi [m]."""

    ax: "_Axis"
    ay: "_Axis"
    row0: int
    row1: int
    z_edges: np.ndarray
    t: float
    z_lo: float
    z_hi: float


def _chords(c, r, kx, ky, strip):
    """Vertical chords of spheres c (C,3), r (C,) through the sample lines of ``strip``'s rows.

    Each sphere is tried against a block of sample lines: in x the run
    [bx - kx, bx + kx] around its centre's sub-interval bx, cut to the box's
    columns (a window of min(2 kx + 1, columns) from max(bx - kx, 0), so a
    sphere much larger than the box costs no more than the box), likewise in
    y cut to the strip's rows. x and y distances are computed per axis and
    broadcast (no gather per candidate). Returns ix, iy (sample column and
    row) and s, e (chord ends clipped to [z_lo, z_hi]) [m] of the non-empty
    chords.
    """
    ax, ay, row0, row1 = strip.ax, strip.ay, strip.row0, strip.row1
    wx = min(2 * kx + 1, ax.n_sub)
    wy = min(2 * ky + 1, row1 - row0)
    bx = np.floor((c[:, 0] - ax.lo) / ax.h).astype(np.int64)
    by = np.floor((c[:, 1] - ay.lo) / ay.h).astype(np.int64)
    x0 = np.maximum(bx - kx, 0)
    y0 = np.maximum(by - ky, row0)
    ix = x0[:, None] + np.arange(wx)                          # (C, wx)
    iy = y0[:, None] + np.arange(wy)                          # (C, wy)
    dx = ax.mid[np.minimum(ix, ax.n_sub - 1)] - c[:, 0, None]
    dy = ay.mid[np.minimum(iy, ay.n_sub - 1)] - c[:, 1, None]
    # Candidates past the last column or row get a distance beyond any radius.
    far2 = (4.0 * float(r.max())) ** 2
    dx2 = np.where(ix < ax.n_sub, dx * dx, far2)
    dy2 = np.where(iy < row1, dy * dy, far2)
    half2 = (r * r)[:, None, None] - dx2[:, :, None] - dy2[:, None, :]
    hit = half2 > 0.0
    sphere, a, b = np.nonzero(hit)
    half = np.sqrt(half2[hit])
    zc = c[sphere, 2]
    s = np.maximum(zc - half, strip.z_lo)
    e = np.minimum(zc + half, strip.z_hi)
    keep = e > s
    sphere, s, e = sphere[keep], s[keep], e[keep]
    return x0[sphere] + a[keep], y0[sphere] + b[keep], s, e


def _accumulate(image, ix, iy, s, e, strip):
    """Add the union volume of chords in ``strip``'s sample rows [row0, row1) to ``image`` [m^3].

    image: (layers*H*W,) float64. ix, iy: sample column and row; s, e: chord
    ends [m]. Chords are cut at the layer faces; each (layer, sample line) is
    a group whose chords are merged exactly: sorted by lower end, the length
    a chord adds is max(0, e - max(s, highest e so far in the group)).

    One int64 key sorts them: group << 34 | qs << 17 | qe, with qs, qe the
    ends measured from the layer bottom in units of t / 2^16 (rounded; 1.5 nm
    for a 0.1 mm layer, far below the sampling error). An in-place integer
    sort is twice as fast as an argsort, and the group bits make one running
    maximum serve all groups (a group's keys all exceed the previous group's).
    """
    ax, ay, row0, row1, z_edges, t = (strip.ax, strip.ay, strip.row0, strip.row1,
                                      strip.z_edges, strip.t)
    n_layers = z_edges.size - 1
    layer = np.clip(np.floor((s - z_edges[0]) / t).astype(np.int64), 0, n_layers - 1)
    # Chords crossing a layer face are cut there; the part above becomes a new
    # chord of the next layer (again, while it spans more faces). Only the
    # crossing chords (about 15 % in a 0.1 mm layer) are touched.
    pieces = [(ix, iy, s, e, layer)]
    while True:
        ix_c, iy_c, s_c, e_c, l_c = pieces[-1]
        face = z_edges[l_c + 1]
        cross = np.flatnonzero((e_c > face) & (l_c < n_layers - 1))
        if cross.size == 0:
            break
        pieces.append((ix_c[cross], iy_c[cross], face[cross], e_c[cross], l_c[cross] + 1))
        e_c[cross] = face[cross]
    if len(pieces) > 1:
        ix, iy, s, e, layer = (np.concatenate(p) for p in zip(*pieces))
    rows, n_cols = row1 - row0, ax.n_sub
    bottom = z_edges[layer]
    scale = _Q_LEVELS / t
    key = (layer * rows + (iy - row0)) * n_cols + ix
    key <<= 2 * _Q_BITS
    key |= np.rint((s - bottom) * scale).astype(np.int64) << _Q_BITS
    key |= np.rint((e - bottom) * scale).astype(np.int64)
    key.sort(kind="stable")   # timsort: the chords arrive in partly sorted runs
    mask = (1 << _Q_BITS) - 1
    group_bits = key >> (2 * _Q_BITS) << (2 * _Q_BITS)
    start = group_bits | ((key >> _Q_BITS) & mask)       # group << 34 | qs
    top = group_bits | (key & mask)                      # group << 34 | qe
    reach = np.maximum.accumulate(top)
    np.maximum(start[1:], reach[:-1], out=start[1:])
    covered = np.maximum(top - start, 0).astype(np.float64) * (t / _Q_LEVELS)   # [m]
    group = group_bits >> (2 * _Q_BITS)
    n_groups = n_layers * rows * n_cols
    line = np.bincount(group, weights=covered, minlength=n_groups).reshape(n_layers, rows, n_cols)
    line *= ay.w[row0:row1, None] * ax.w[None, :]                               # [m^3]
    H, W = ay.n_cells, ax.n_cells
    pix = ((np.arange(n_layers)[:, None, None] * H + ay.cell_of[None, row0:row1, None]) * W
           + ax.cell_of[None, None, :])
    image += np.bincount(pix.ravel(), weights=line.ravel(), minlength=image.size)


def _union_numpy(image, c, r, grid, rows):
    """Add the union volume [m^3] of spheres c (C,3), r (C,) per cell to image (flat), numpy.

    grid: the _Strip of all sample rows; rows: sample rows per strip."""
    ax, ay = grid.ax, grid.ay
    # Radius classes, each with its own block of sample offsets, so that a
    # few big spheres do not inflate the block of all the others.
    kx = np.ceil(r / ax.h).astype(np.int64)
    ky = np.ceil(r / ay.h).astype(np.int64)
    label = kx * (ky.max() + 1) + ky
    classes = []
    for lab in np.unique(label):
        sel = np.flatnonzero(label == lab)
        sel = sel[np.argsort(c[sel, 1], kind="stable")]   # by y, for the strips
        r_max = float(r[sel].max())
        classes.append((c[sel], r[sel], r_max, _reach(r_max, ax.h), _reach(r_max, ay.h)))
    for row0 in range(0, ay.n_sub, rows):
        row1 = min(row0 + rows, ay.n_sub)
        y0, y1 = ay.lo + row0 * ay.h, ay.lo + row1 * ay.h
        strip = _Strip(ax, ay, row0, row1, grid.z_edges, grid.t, grid.z_lo, grid.z_hi)
        parts = []
        for cc, rr, r_max, kx_c, ky_c in classes:
            i0, i1 = np.searchsorted(cc[:, 1], [y0 - r_max, y1 + r_max])
            block = min(2 * kx_c + 1, ax.n_sub) * min(2 * ky_c + 1, row1 - row0)
            step = max(1, _CHUNK_CANDIDATES // block)
            for i in range(i0, i1, step):
                j = min(i + step, i1)
                parts.append(_chords(cc[i:j], rr[i:j], kx_c, ky_c, strip))
        if parts:
            ix, iy, s, e = (np.concatenate(p) for p in zip(*parts))
            if s.size:
                _accumulate(image, ix, iy, s, e, strip)


def pixelate_spheres(centers, radii, lo, hi, cell_xy=DEFAULT_CELL,
                     layer_thickness=DEFAULT_LAYER_THICKNESS, *, spacing=None, engine="auto"):
    """Volume fractions of the union of spheres in the cells of a box.

    centers (N,3) [m], radii (N,) [m]; lo, hi (3,) box corners [m], hi > lo;
    cell_xy = (cell_x, cell_y) [m]; layer_thickness [m]; spacing: in-plane
    sample spacing [m] (default: min(median radius / 6, cell_x / 2,
    cell_y / 2); each cell gets ceil(cell / spacing) samples per side);
    engine: "auto", "numpy" or "compiled", the same image bit for bit at
    another speed (:func:`amfe.dataset.pixelkernel.use_kernel`).

    Returns image (layers, H, W) float32 in [0, 1]: H = ceil(Ly / cell_y)
    rows along y, W = ceil(Lx / cell_x) columns along x, layers =
    ceil(Lz / layer_thickness) (L = hi - lo; a side within 1e-9 relative of a
    whole number of cells gets no sliver cell). Layer 0 is at the bottom
    (z = lo_z), row 0 at y = lo_y, column 0 at x = lo_x. Pixel = volume of the
    union of the spheres inside the cell / volume of the cell inside the box:
    when a side does not divide evenly the last cells are partial, and their
    fraction is relative to the part inside the box (a fully packed region
    reads the same in a partial cell as in a whole one). Only the parts of the
    spheres inside the box count. Accurate to about 0.1 % of a cell volume at
    the default spacing (see the module docstring).

    Raises AmfeError for bad particles (empty, non-finite, radius <= 0),
    non-positive cell sizes, layer thickness or spacing, and boxes with
    hi <= lo on some axis.
    """
    centers, radii = validate_particles(centers, radii)
    use_kernel(engine, False)   # a bad engine is refused whatever the bed
    cell_x, cell_y = _check_cell(cell_xy)
    t = _positive("layer thickness", layer_thickness)
    lo, hi = _check_box(lo, hi)
    if spacing is None:
        spacing = min(float(np.median(radii)) / SAMPLES_PER_RADIUS, cell_x / 2, cell_y / 2)
    else:
        spacing = _positive("sample spacing", spacing)
    ax = _Axis(lo[0], hi[0], cell_x, max(1, math.ceil(cell_x / spacing - _DIVIDE_TOL)))
    ay = _Axis(lo[1], hi[1], cell_y, max(1, math.ceil(cell_y / spacing - _DIVIDE_TOL)))
    z_edges = _layer_edges(lo[2], hi[2], t)
    n_layers, H, W = z_edges.size - 1, ay.n_cells, ax.n_cells
    image = np.zeros(n_layers * H * W)

    inside = np.ones(radii.size, bool)   # spheres reaching into the box, column by column
    for a in range(3):                   # (10x faster than np.all(..., axis=1))
        inside &= (centers[:, a] + radii > lo[a]) & (centers[:, a] - radii < hi[a])
    c, r = (centers, radii) if inside.all() else (centers[inside], radii[inside])
    if r.size:
        # Strips of sample rows, each holding about _TILE_CHORDS chords and at
        # most _MAX_GROUPS (layer, sample line) groups.
        line_groups = n_layers * ax.n_sub
        if line_groups > _MAX_GROUPS:
            raise AmfeError(f"image too large: {n_layers} layers x {ax.n_sub} sample columns per "
                            f"sample row exceed {_MAX_GROUPS}; use larger cells, layers or spacing")
        est = float(np.sum(np.pi * r**2)) / (ax.h * ay.h) * (1.0 + float(np.mean(2 * r)) / t)
        rows = min(math.ceil(ay.n_sub / max(1.0, est / _TILE_CHORDS)), _MAX_GROUPS // line_groups)
        grid = _Strip(ax, ay, 0, ay.n_sub, z_edges, t, lo[2], hi[2])
        if use_kernel(engine, est >= _KERNEL_FROM):
            union_volumes(c, r, grid, rows, _Q_LEVELS, image)
        else:
            _union_numpy(image, c, r, grid, rows)

    volume = (np.diff(z_edges)[:, None, None] * ay.cell_w[None, :, None]
              * ax.cell_w[None, None, :])
    frac = image.reshape(n_layers, H, W) / volume
    return np.clip(frac, 0.0, 1.0).astype(np.float32)


def image_box(bed, box=None):
    """The box (lo (3,), hi (3,)) [m] that :func:`pixelate` images.

    ``box`` = (lo, hi) if given; else [0, attrs['size']] when the bed records
    its size (generated beds); else the bounding box of the spheres
    (centres -/+ radii).
    """
    if box is not None:
        try:
            lo, hi = box
        except (TypeError, ValueError):
            raise AmfeError(f"box must be a pair (lo, hi) of 3-vectors in m, got {box!r}") from None
        return _check_box(lo, hi)
    size = bed.attrs.get("size") if hasattr(bed, "attrs") else None
    if size is not None:
        return _check_box(np.zeros(3), size)
    centers, radii = validate_particles(bed.centers, bed.radii)
    return _check_box((centers - radii[:, None]).min(axis=0),
                      (centers + radii[:, None]).max(axis=0))


def pixelate(bed, cell=DEFAULT_CELL, layer_thickness=None, box=None, *, spacing=None,
             engine="auto"):
    """The paper's image of a bed (section 6): (layers, H, W) float32 volume fractions.

    bed: :class:`amfe.model.bed.Bed` (centres, radii [m], attrs); cell = (cell_x,
    cell_y) [m], default 0.03 mm x 0.03 mm; layer_thickness [m]: the argument,
    else attrs['layer_thickness'], else 0.1 mm; box: (lo, hi) [m], else
    [0, attrs['size']], else the spheres' bounding box (:func:`image_box`);
    spacing: in-plane sample spacing [m] (default median radius / 6); engine as
    in :func:`pixelate_spheres`.

    Pixel [l, i, j]: fraction of the cell [lo_x + j cell_x, ...) x
    [lo_y + i cell_y, ...) x [lo_z + l t, ...) inside the box that the union
    of the particles fills, 0 empty to 1 full; partial cells at the box's far
    faces are measured relative to their part inside the box. A 3 mm x 3 mm x
    0.3 mm bed gives a 3 x 100 x 100 image. See :func:`pixelate_spheres`.
    """
    if not (hasattr(bed, "centers") and hasattr(bed, "radii")):
        raise AmfeError(f"bed must be an amfe.model.bed.Bed, got {type(bed).__name__}")
    if layer_thickness is None:
        layer_thickness = getattr(bed, "attrs", {}).get("layer_thickness", DEFAULT_LAYER_THICKNESS)
    lo, hi = image_box(bed, box)
    return pixelate_spheres(bed.centers, bed.radii, lo, hi, cell, layer_thickness, spacing=spacing,
                            engine=engine)

"""The bond-stiffness image of a bed: how stiff the sintered necks in each cell are.

The volume-fraction image (:mod:`amfe.dataset.images`) barely shows the neck size at
0.03 mm cells, yet the moduli hang on it (docs/surrogate_diagnosis.md). This
image gives the surrogate that information on the same grid: pixel
[l, i, j] is

    sum over the bonds whose midpoint lies in the cell of  k_n L^2 / (E V_cell)

with k_n the bond's normal spring (paper eq. 1, :func:`amfe.model.bonds.bond_springs`)
[N/m], L its centre distance [m], E the particles' Young's modulus [Pa] and
V_cell the cell's volume inside the box [m^3]. k_n L^2 / V is the bond's
share of the Voigt (affine) estimate of the normal stiffness, so a pixel is
a dimensionless local stiffness density, unchanged by the unit of length or
of stress (about 0.5 to 3 in `small` beds). Bonds whose midpoint lies outside
the box are left out. The bonds are find_pairs' (by the C bond finder where it
builds, amfe.model.pairkernel); from 20 000 particles numba's loops (amfe.dataset._jit)
sum the springs, the same image bit for bit: 0.066 s for a 3 mm bed, 2.8x faster than
before the C bond finder.
"""
import numpy as np

from amfe.dataset.images import DEFAULT_CELL, DEFAULT_LAYER_THICKNESS, image_box
from amfe.dataset.pixelkernel import use_numba
from amfe.errors import AmfeError
from amfe.model import pairkernel
from amfe.model.bonds import COINCIDENT, bond_springs, find_bonds, find_pairs, neck
from amfe.model.springs import A_STAR_MARGIN, critical_a_star, spring_constants, spring_model

_KERNEL_FROM = 20_000   # particles from which engine "auto" sums the springs with numba
NO_CAP_FIX = ("Reduce the particle overlaps: a bond image (amfe predict's input, amfe dataset's "
              "bond images) takes no a* cap; amfe homogenize BED --cap-a-star A solves such a "
              "bed with the bonds capped.")


def _compiled_sums(centers, radii, material, box, springs="paper"):
    """The bond image's per-cell sums of k_n L^2 (flat, float64) by numba's kernel, or None
    where it steps aside (a bond that the numpy path refuses, which names it). The bonds
    and lengths are the C bond finder's, else find_pairs' KD-tree's (which names coincident
    centres). box = (lo, hi, cell, n) as in amfe.dataset._jit.bond_sums_for; springs: the
    spring model (amfe.model.springs.SPRING_MODELS) whose k_n the kernel is compiled with."""
    from amfe.dataset._jit import bond_sums_for
    c, r = np.ascontiguousarray(centers, np.float64), np.ascontiguousarray(radii, np.float64)
    # find_pairs' bonds and contact_geometry's lengths, bit for bit, by the C bond finder
    found = pairkernel.bonds(c, r, 2.0 * COINCIDENT)
    if found is None:
        i, j = find_pairs(c, r)   # the KD-tree's (an AmfeError for coincident centres)
        branch = c[j] - c[i]
        found = (i, j, np.sqrt(np.einsum("ij,ij->i", branch, branch)))
    model = spring_model(springs)
    consts = (tuple(float(v) for v in model.coefficients(material)),
              critical_a_star(material.nu, material.psi) - A_STAR_MARGIN, COINCIDENT)
    sums = np.zeros(int(np.prod(box[3])))
    ok = bond_sums_for(springs)(c, r, found, consts,
                   tuple(np.ascontiguousarray(v) for v in box), sums)
    return sums if ok else None


def _numpy_sums(centers, radii, material, box, a_star_cap):
    """The per-cell sums of k_n L^2 (flat, float64), numpy (the bonds by find_bonds, whose
    pairs the C bond finder gives where it builds)."""
    bonds = find_bonds(centers, radii)
    if not len(bonds):
        return np.zeros(int(np.prod(box[3])))
    k_n = bond_springs(bonds, material, a_star_cap=a_star_cap, fix=NO_CAP_FIX)[0]
    return _binned(centers, bonds.i, bonds.j, k_n * bonds.length**2, box)


def _lean_sums(centers, radii, material, box):
    """:func:`_numpy_sums` without a cap, bit for bit, on the C bond finder's bonds and
    lengths: contact_geometry's and bond_springs' arithmetic for k_n alone (2x faster on a
    `small` bed); None where that finder does not run or a bond needs their checks, which
    name it (the caller then takes :func:`_numpy_sums`)."""
    c, r = np.asarray(centers, np.float64), np.asarray(radii, np.float64)
    found = pairkernel.bonds(c, r, 2.0 * COINCIDENT)
    if found is None:
        return None
    i, j, length = found
    d_i, a, r_eff = neck(length, r[i], r[j])
    a_star = a / r_eff
    limit = critical_a_star(material.nu, material.psi) - A_STAR_MARGIN
    if np.any((d_i <= 0) | (length - d_i <= 0)) or np.any(a_star >= limit):
        return None
    k_n = spring_constants(a_star * r_eff, r_eff, material)[0]
    return _binned(c, i, j, k_n * length**2, box)


def _binned(centers, i, j, weights, box):
    """weights (M,) of the bonds (i, j) summed in the cells of their midpoints (flat)."""
    lo, hi, cell, n = box
    mid = 0.5 * (np.asarray(centers, np.float64)[i] + np.asarray(centers, np.float64)[j])
    idx = np.floor((mid - lo) / cell).astype(np.int64)
    inside = np.ones(mid.shape[0], bool)
    for a in range(3):   # column by column: 10x faster than np.all(..., axis=1)
        inside &= (mid[:, a] >= lo[a]) & (mid[:, a] < hi[a])
    idx = np.minimum(idx, n - 1)[inside]
    flat = (idx[:, 2] * n[1] + idx[:, 1]) * n[0] + idx[:, 0]
    return np.bincount(flat, weights=weights[inside], minlength=int(n[2] * n[1] * n[0]))


def bond_image_of(centers, radii, material, lo, hi, cell_xy=DEFAULT_CELL,
                  layer_thickness=DEFAULT_LAYER_THICKNESS, a_star_cap=None):
    """Bond-stiffness image (layers, H, W) float32 of the spheres, on pixelate's grid.

    centers (N, 3) [m], radii (N,) [m], material: amfe.model.material.Material;
    lo, hi (3,) [m]: the box; cell_xy (2,) [m], layer_thickness [m]: the cell
    (the grid of :func:`amfe.dataset.images.pixelate_spheres`: partial cells at the
    far faces). ``a_star_cap`` as in bond_springs (default: a bond past the
    critical a* is an error).
    """
    return _image_of(centers, radii, material, (lo, hi, cell_xy, layer_thickness), a_star_cap,
                     "auto")


def _image_of(centers, radii, material, grid, a_star_cap, engine):
    """:func:`bond_image_of` with grid = (lo, hi, cell_xy, layer_thickness) and the engine
    ("auto", "numpy" or "compiled": the same image bit for bit, the springs summed by numba
    or numpy as amfe.dataset.pixelkernel.use_numba says)."""
    use_numba(engine, False)   # a bad engine is refused whatever the bed
    lo, hi, cell_xy, layer_thickness = grid
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    cell = np.array([cell_xy[0], cell_xy[1], layer_thickness], np.float64)
    if not (np.all(np.isfinite(cell)) and np.all(cell > 0)):
        raise AmfeError(f"cell sizes must be positive, got {cell.tolist()} m")
    n = np.maximum(np.ceil((hi - lo) / cell - 1e-9).astype(int), 1)   # (nx, ny, nz)
    edges = [np.minimum(lo[a] + cell[a] * np.arange(n[a] + 1), hi[a]) for a in range(3)]
    widths = [np.diff(e) for e in edges]
    volume = widths[2][:, None, None] * widths[1][None, :, None] * widths[0][None, None, :]

    sums = None
    if a_star_cap is None and use_numba(engine, np.size(radii) >= _KERNEL_FROM):
        sums = _compiled_sums(centers, radii, material, (lo, hi, cell, n.astype(np.int64)))
    if sums is None and a_star_cap is None and engine != "numpy":
        sums = _lean_sums(centers, radii, material, (lo, hi, cell, n))
    if sums is None:
        sums = _numpy_sums(centers, radii, material, (lo, hi, cell, n), a_star_cap)
    out = sums.reshape(n[2], n[1], n[0]) / (volume * float(material.E))
    return out.astype(np.float32)


def bond_image(bed, cell=DEFAULT_CELL, layer_thickness=None, box=None, a_star_cap=None,
               engine="auto"):
    """The bond-stiffness image of ``bed`` on the grid :func:`amfe.dataset.images.pixelate` uses.

    Same arguments as pixelate (box default: [0, attrs['size']], else the
    spheres' bounding box, and engine); the material is ``bed.material()``.
    Returns (layers, H, W) float32, dimensionless (module docstring).
    """
    if not (hasattr(bed, "centers") and hasattr(bed, "radii")):
        raise AmfeError(f"bed must be an amfe.model.bed.Bed, got {type(bed).__name__}")
    if layer_thickness is None:
        layer_thickness = getattr(bed, "attrs", {}).get("layer_thickness", DEFAULT_LAYER_THICKNESS)
    lo, hi = image_box(bed, box)
    return _image_of(bed.centers, bed.radii, bed.material(), (lo, hi, cell, layer_thickness),
                     a_star_cap, engine)

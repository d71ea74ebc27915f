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
the box are left out. It takes about 30 ms for a `small` bed; from 20 000
particles compiled loops (amfe.dataset._jit) give the same image bit for bit,
3x faster on a 3 mm bed.
"""
import numpy as np

from amfe.dataset.images import DEFAULT_CELL, DEFAULT_LAYER_THICKNESS, image_box
from amfe.dataset.pixelkernel import use_kernel
from amfe.errors import AmfeError
from amfe.model.bonds import COINCIDENT, bond_springs, contact_geometry, find_bonds
from amfe.model.springs import A_STAR_MARGIN, critical_a_star, spring_model

_KERNEL_FROM = 20_000   # particles from which engine "auto" finds the bonds compiled
NO_CAP_FIX = ("Reduce the particle overlaps: a bond image (amfe predict's input, amfe dataset's "
              "bond images) takes no a* cap; amfe homogenize BED --cap-a-star A solves such a "
              "bed with the bonds capped.")


def _find_bonds(centers, radii, engine):
    """:func:`amfe.model.bonds.find_bonds` of the particles: the same bonds in the same order.

    With the compiled kernel (engine as in amfe.dataset.pixelkernel.use_kernel) a
    cell list finds find_pairs' bonds, sorted, and contact_geometry measures them; a
    bed with coincident centres (or too sparse for the cell table) goes the numpy
    way, which names them.
    """
    centers, radii = np.asarray(centers, float), np.asarray(radii, float)
    if use_kernel(engine, radii.size >= _KERNEL_FROM) and radii.size:
        from amfe.model._jit_pairs import bonds
        found = bonds(np.ascontiguousarray(centers), np.ascontiguousarray(radii))
        if found is not None:
            return contact_geometry(centers, radii, *found[:2])
    return find_bonds(centers, radii)


def _compiled_sums(centers, radii, material, box, springs="paper"):
    """The bond image's per-cell sums of k_n L^2 (flat, float64) by the compiled kernels, or
    None where they step aside (coincident centres, a bed too sparse, a bond that the numpy
    path refuses). box = (lo, hi, cell, n) as in amfe.dataset._jit.bond_sums_for; springs:
    the spring model (amfe.model.springs.SPRING_MODELS) whose k_n the kernel is compiled with."""
    from amfe.dataset._jit import bond_sums_for
    from amfe.model._jit_pairs import bonds
    c, r = np.ascontiguousarray(centers, np.float64), np.ascontiguousarray(radii, np.float64)
    found = bonds(c, r)   # find_pairs' bonds and contact_geometry's lengths, bit for bit
    if found is None:
        return None
    model = spring_model(springs)
    consts = (tuple(float(v) for v in model.coefficients(material)),
              critical_a_star(material.nu, material.psi) - A_STAR_MARGIN, COINCIDENT)
    sums = np.zeros(int(np.prod(box[3])))
    ok = bond_sums_for(springs)(c, r, found, consts,
                   tuple(np.ascontiguousarray(v) for v in box), sums)
    return sums if ok else None


def _numpy_sums(centers, radii, material, box, a_star_cap, engine):
    """The per-cell sums of k_n L^2 (flat, float64), numpy (the bonds by :func:`_find_bonds`)."""
    lo, hi, cell, n = box
    bonds = _find_bonds(centers, radii, engine)
    if not len(bonds):
        return np.zeros(int(n[2] * n[1] * n[0]))
    k_n = bond_springs(bonds, material, a_star_cap=a_star_cap, fix=NO_CAP_FIX)[0]
    mid = 0.5 * (np.asarray(centers, np.float64)[bonds.i]
                 + np.asarray(centers, np.float64)[bonds.j])
    idx = np.floor((mid - lo) / cell).astype(np.int64)
    inside = np.all((mid >= lo) & (mid < hi), axis=1)
    idx = np.minimum(idx, n - 1)[inside]
    flat = (idx[:, 2] * n[1] + idx[:, 1]) * n[0] + idx[:, 0]
    return np.bincount(flat, weights=(k_n * bonds.length**2)[inside],
                       minlength=int(n[2] * n[1] * n[0]))


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
    ("auto", "numpy" or "compiled": the same image bit for bit, :func:`_find_bonds`)."""
    use_kernel(engine, False)   # a bad engine is refused whatever the bed
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
    if a_star_cap is None and use_kernel(engine, np.size(radii) >= _KERNEL_FROM):
        sums = _compiled_sums(centers, radii, material, (lo, hi, cell, n.astype(np.int64)))
    if sums is None:
        sums = _numpy_sums(centers, radii, material, (lo, hi, cell, n), a_star_cap, engine)
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

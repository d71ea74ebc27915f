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
the box are left out. It takes about 30 ms for a `small` bed.
"""
import numpy as np

from amfe.model.bonds import bond_springs, find_bonds
from amfe.errors import AmfeError
from amfe.dataset.images import DEFAULT_CELL, DEFAULT_LAYER_THICKNESS, image_box


def bond_image_of(centers, radii, material, lo, hi, cell_xy=DEFAULT_CELL,
                  layer_thickness=DEFAULT_LAYER_THICKNESS, a_star_cap=None):
    """Bond-stiffness image (layers, H, W) float32 of the spheres, on pixelate's grid.

    centers (N, 3) [m], radii (N,) [m], material: amfe.model.material.Material;
    lo, hi (3,) [m]: the box; cell_xy (2,) [m], layer_thickness [m]: the cell
    (the grid of :func:`amfe.dataset.images.pixelate_spheres`: partial cells at the
    far faces). ``a_star_cap`` as in bond_springs (default: a bond past the
    critical a* is an error).
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    cell = np.array([cell_xy[0], cell_xy[1], layer_thickness], np.float64)
    if not (np.all(np.isfinite(cell)) and np.all(cell > 0)):
        raise AmfeError(f"cell sizes must be positive, got {cell.tolist()} m")
    n = np.maximum(np.ceil((hi - lo) / cell - 1e-9).astype(int), 1)   # (nx, ny, nz)
    edges = [np.minimum(lo[a] + cell[a] * np.arange(n[a] + 1), hi[a]) for a in range(3)]
    widths = [np.diff(e) for e in edges]
    volume = widths[2][:, None, None] * widths[1][None, :, None] * widths[0][None, None, :]

    bonds = find_bonds(centers, radii)
    image = np.zeros(int(n[2] * n[1] * n[0]))
    if len(bonds):
        k_n = bond_springs(bonds, material, a_star_cap=a_star_cap)[0]
        mid = 0.5 * (np.asarray(centers, np.float64)[bonds.i]
                     + np.asarray(centers, np.float64)[bonds.j])
        idx = np.floor((mid - lo) / cell).astype(np.int64)
        inside = np.all((mid >= lo) & (mid < hi), axis=1)
        idx = np.minimum(idx, n - 1)[inside]
        flat = (idx[:, 2] * n[1] + idx[:, 1]) * n[0] + idx[:, 0]
        image = np.bincount(flat, weights=(k_n * bonds.length**2)[inside], minlength=image.size)
    out = image.reshape(n[2], n[1], n[0]) / (volume * float(material.E))
    return out.astype(np.float32)


def bond_image(bed, cell=DEFAULT_CELL, layer_thickness=None, box=None, a_star_cap=None):
    """The bond-stiffness image of ``bed`` on the grid :func:`amfe.dataset.images.pixelate` uses.

    Same arguments as pixelate (box default: [0, attrs['size']], else the
    spheres' bounding box); the material is ``bed.material()``.
    Returns (layers, H, W) float32, dimensionless (module docstring).
    """
    if not (hasattr(bed, "centers") and hasattr(bed, "radii")):
        raise AmfeError(f"bed must be an amfe.model.bed.Bed, got {type(bed).__name__}")
    if layer_thickness is None:
        layer_thickness = getattr(bed, "attrs", {}).get("layer_thickness", DEFAULT_LAYER_THICKNESS)
    lo, hi = image_box(bed, box)
    return bond_image_of(bed.centers, bed.radii, bed.material(), lo, hi, cell, layer_thickness,
                         a_star_cap=a_star_cap)

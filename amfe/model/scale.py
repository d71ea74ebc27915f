"""The record of a data-set scale, :class:`Scale` (the distribution its beds are drawn from,
amfe.model.scales), and the built-in scales, :data:`SCALES`. The box scales of any size
(amfe.model.boxscale) are Scales too; both modules import this one."""
import math
from dataclasses import dataclass

MM = 1e-3
UM = 1e-6
# A side this close (in cells) to a whole number of cells is that whole number (as in
# training/anysize.py: 0.6e-3 / 30e-6 is 19.999999999999996 in floating point).
WHOLE_CELL_TOL = 1e-6


def _whole_cells(length, cell):
    return int(math.floor(length / cell + WHOLE_CELL_TOL))


@dataclass(frozen=True)
class Scale:
    """The distribution of one data-set scale; lengths in m, angles in degrees."""

    name: str
    size: tuple                      # (Lx, Ly, Lz) of the box
    layer_thickness: float = 0.1 * MM
    cell: tuple = (30 * UM, 30 * UM)  # image cell (x, y); z: one powder layer
    image_spacing: float = 2.5 * UM  # in-plane sample spacing of amfe.dataset.images.pixelate
    mean_radius: float = 12.5 * UM
    jitter: float = 0.025
    a_star_max: float = 0.98
    enlargement_lo: float = 1.05
    enlargement_hi: tuple = (1.06, 1.14)
    track_width: tuple = (0.05 * MM, 0.15 * MM)
    coverage: tuple = (0.35, 1.0)    # track width / hatch spacing
    layer_rotations: tuple = (67.0, 90.0)
    skip_probability: float = 0.5    # share of beds with skipped track pieces
    skip_fraction: tuple = (0.05, 0.3)
    skip_length: tuple = (0.1 * MM, 0.3 * MM)
    empty_probability: float = 0.0   # tests only: share of deliberately empty beds
    purpose: str = ""
    # Box scales (amfe.model.boxscale): "steel", an alloy of amfe.model.material.ALLOYS, or
    # "draw" (nu, psi uniform in nu_range, psi_range; E steel's) from a stream of its own.
    material: str = "steel"
    nu_range: tuple = None
    psi_range: tuple = None

    @property
    def n_layers(self):
        return max(1, int(math.ceil(self.size[2] / self.layer_thickness - 1e-9)))

    @property
    def image_shape(self):
        """(layers, H, W) = (powder layers, whole cells along y, whole cells along x)."""
        return (self.n_layers, _whole_cells(self.size[1], self.cell[1]),
                _whole_cells(self.size[0], self.cell[0]))

    @property
    def image_box(self):
        """The imaged box's far corner (x, y, z) [m]: the size itself when its sides are whole
        cells, else x and y cropped to whole cells (the whole-cell rule of training/anysize.py:
        the strip under one cell wide is not imaged)."""
        nx, ny = _whole_cells(self.size[0], self.cell[0]), _whole_cells(self.size[1], self.cell[1])
        if all(abs(L / c - n) <= WHOLE_CELL_TOL for L, c, n in
               ((self.size[0], self.cell[0], nx), (self.size[1], self.cell[1], ny))):
            return self.size
        return (nx * self.cell[0], ny * self.cell[1], self.size[2])

    def describe(self):
        lx, ly, lz = (s / MM for s in self.size)
        return (f"{self.name}: {lx:g} x {ly:g} x {lz:g} mm, {self.n_layers} layer(s) of "
                f"{self.layer_thickness / MM:g} mm, images {'x'.join(map(str, self.image_shape))}")


SCALES = {
    "small": Scale("small", (0.6 * MM, 0.6 * MM, 0.3 * MM),
                   purpose="2 000 beds in under an hour on 2 cores"),
    "medium": Scale("medium", (1.2 * MM, 1.2 * MM, 0.3 * MM),
                    purpose="twice the small side, images 3 x 40 x 40; for the any-size surrogate"),
    "paper": Scale("paper", (3.0 * MM, 3.0 * MM, 0.3 * MM),
                   purpose="the paper's 3 x 3 mm x 3 layers, 3 x 100 x 100 images; for clusters"),
    "tiny": Scale("tiny", (0.15 * MM, 0.15 * MM, 0.1 * MM), empty_probability=0.2,
                  purpose="test suite only; a fifth of the beds are empty on purpose"),
}

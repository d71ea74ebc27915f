"""Box scales: the ``small`` scale's distribution at any box and with any material (issue 46).

``amfe dataset --size X Y Z [--materials M | --nu LO HI --psi LO HI]`` makes
beds whose generation parameters are drawn exactly as ``small``'s
(:func:`amfe.model.scales.sample_bed_params`: the same draws from the same
stream, so a bed seed gives the same scan path at every box), in a box of
X x Y x Z mm, of a fixed or drawn particle material. The whole distribution
is written into the scale's name, which every file of a data set records as
its ``scale`` (data set, parts, label tables, their shard names): a shard of
one box or material can never join another's, and ``get_scale(name)`` gives
the distribution back from a file alone.

Name: ``box{X}x{Y}x{Z}um`` (integers, micrometres), then for a material
other than steel ``_{alloy}`` (an :data:`amfe.model.material.ALLOYS` name:
316L, Ti64, IN718, AlSi10Mg) or ``_nu{LO}to{HI}psi{LO}to{HI}`` (thousandths)
for drawn materials; e.g. ``box900x900x300um``, ``box600x600x300um_Ti64``,
``box600x600x200um_nu250to400psi40to120``. The name is canonical: parsing
and writing it again gives the same string.

Rules (each refused with a one-line AmfeError):

- the sides are given to the micrometre; x and y from 0.06 mm (two image
  cells) to 10 mm; a side that is not a whole number of 0.03 mm cells is
  imaged on its whole cells from the origin, the remainder strip (under one
  cell) cropped (``Scale.image_box``, the whole-cell rule of
  training/anysize.py); the bed and its label keep the full box;
- the height is a whole number of 0.1 mm powder layers, 1 to
  :data:`MAX_LAYERS` (a partial layer is refused: the generator stacks
  whole layers and an image channel is one layer);
- drawn materials: nu ~ U(LO, HI) and psi ~ U(LO, HI) from
  ``default_rng([bed_seed, MATERIAL_STREAM])`` (a stream of their own: the
  bed's other draws stay those of ``small``); E and the density stay
  steel's, because every spring is E times a function of a*, R, nu and psi
  (amfe.model.springs), so the moduli scale exactly with E (tests check it)
  and a surrogate takes E by scaling. Ranges: 0 <= nu < 0.5, 0 <= psi <=
  :data:`PSI_MAX`. Default ranges (``--materials draw``): :data:`DEFAULT_NU`,
  :data:`DEFAULT_PSI`;
- a*: nu and psi move the critical a* (amfe.model.springs.critical_a_star);
  the bed's a* bound is min(0.98, critical a* - :data:`A_STAR_GAP`)
  (:func:`a_star_cap`), so that no bond comes near the pole of k_n and
  kappa_t. It is 0.98 (the beds are the steel ones) wherever the critical a*
  is at least 0.985: for psi up to 0.1195 at nu = 0.25 (0.1230 at nu = 0.30,
  0.1331 at 0.40). In the corner of the default ranges (nu 0.25, psi 0.12:
  critical a* 0.98488) it is 0.97988; for psi up to 0.2 it falls to 0.955.
  The generator then shrinks a few more radii (n_shrunk) and records the
  bound as the bed's a_star_max. A bound, not a redraw: nu and psi keep
  their uniform distribution.
"""
import re
from functools import lru_cache

import numpy as np

from amfe.errors import AmfeError
from amfe.model.material import ALLOYS, STEEL, Material
from amfe.model.scale import MM, SCALES, Scale
from amfe.model.springs import critical_a_star

MATERIAL_STREAM = 0x3A7E46  # second word of the material stream's SeedSequence
LAYER_UM = 100              # a powder layer [um]
MAX_LAYERS = 10
SIDE_UM = (60, 10000)       # x, y [um]: two cells to 10 mm
DEFAULT_NU = (0.25, 0.40)
DEFAULT_PSI = (0.04, 0.12)
PSI_MAX = 0.2
A_STAR_GAP = 0.005
_NAME = re.compile(r"^box(\d+)x(\d+)x(\d+)um(?:_(\w+))?$")
_DRAW = re.compile(r"^nu(\d+)to(\d+)psi(\d+)to(\d+)$")


def _micrometres(name, mm):
    um = float(mm) * 1000.0
    if not np.isfinite(um) or abs(um - round(um)) > 1e-6:
        raise AmfeError(f"--size {name} = {mm:g} mm: give the sides to the micrometre")
    return int(round(um))


def _thousandths(name, value):
    t = float(value) * 1000.0
    if not np.isfinite(t) or abs(t - round(t)) > 1e-6:
        raise AmfeError(f"{name} {value:g}: give the range to 0.001")
    return int(round(t))


def box_name(size_mm, materials="steel", nu=None, psi=None):
    """The scale name of a box of ``size_mm`` (x, y, z) [mm] with ``materials``.

    materials: "steel", an alloy name (:data:`ALLOYS`) or "draw"; nu, psi:
    (lo, hi) ranges of a drawn material (given: drawn, default
    :data:`DEFAULT_NU`, :data:`DEFAULT_PSI`). AmfeError for any rule of the
    module docstring broken, naming the value.
    """
    if len(size_mm) != 3:
        raise AmfeError(f"--size takes three lengths X Y Z in mm, got {len(size_mm)}")
    x, y, z = (_micrometres(n, v) for n, v in zip("XYZ", size_mm))
    for n, v in (("X", x), ("Y", y)):
        if not SIDE_UM[0] <= v <= SIDE_UM[1]:
            raise AmfeError(f"--size {n} = {v / 1000:g} mm: the sides must lie in "
                            f"[{SIDE_UM[0] / 1000:g}, {SIDE_UM[1] / 1000:g}] mm")
    if z % LAYER_UM or not 1 <= z // LAYER_UM <= MAX_LAYERS:
        raise AmfeError(f"--size Z = {z / 1000:g} mm is {z / LAYER_UM:g} powder layers of "
                        f"{LAYER_UM / 1000:g} mm: give a whole number of layers, 1 to "
                        f"{MAX_LAYERS} (e.g. {max(1, z // LAYER_UM) * LAYER_UM / 1000:g} mm); a "
                        "partial layer is not made")
    name = f"box{x}x{y}x{z}um"
    if nu is not None or psi is not None:
        if materials not in ("steel", "draw"):
            raise AmfeError(f"--nu/--psi draw the material; they cannot go with --materials "
                            f"{materials}")
        materials = "draw"
    if materials == "steel":
        return name
    if materials in ALLOYS:
        return f"{name}_{materials}"
    if materials != "draw":
        raise AmfeError(f"--materials {materials!r}: choose steel, draw or one of "
                        f"{', '.join(ALLOYS)}")
    lo_hi = []
    for flag, rng, top in (("--nu", nu or DEFAULT_NU, 0.499), ("--psi", psi or DEFAULT_PSI,
                                                               PSI_MAX)):
        lo, hi = (_thousandths(flag, v) for v in rng)
        if not 0 <= lo <= hi <= round(top * 1000):
            raise AmfeError(f"{flag} {rng[0]:g} {rng[1]:g}: need 0 <= LO <= HI <= {top:g}")
        lo_hi += [lo, hi]
    return name + "_nu{}to{}psi{}to{}".format(*lo_hi)


@lru_cache(maxsize=256)
def parse_box(name):
    """The :class:`amfe.model.scales.Scale` of box scale ``name``; AmfeError if it is none."""

    m = _NAME.match(name)
    bad = AmfeError(f"unknown scale {name!r}; choose one of {', '.join(SCALES)}, or a box scale "
                    "(`amfe dataset --size X Y Z`; amfe.model.boxscale)")
    if not m:
        raise bad
    x, y, z = (int(g) for g in m.group(1, 2, 3))
    suffix = m.group(4)
    material, nu, psi = "steel", None, None
    if suffix in ALLOYS:
        material = suffix
    elif suffix is not None:
        d = _DRAW.match(suffix)
        if not d:
            raise bad
        lo_nu, hi_nu, lo_psi, hi_psi = (int(g) / 1000 for g in d.groups())
        material, nu, psi = "draw", (lo_nu, hi_nu), (lo_psi, hi_psi)
    if box_name((x / 1000, y / 1000, z / 1000), material, nu, psi) != name:
        raise bad   # not canonical (leading zeros, a steel suffix, ...)
    return Scale(name, (x / 1000 * MM, y / 1000 * MM, z / 1000 * MM), material=material,
                 nu_range=nu, psi_range=psi,
                 purpose="the small scale's scan paths at this box (amfe dataset --size)")


def draw_material(sc, bed_seed):
    """The particle :class:`Material` of the bed with seed ``bed_seed`` of box scale ``sc``."""
    if sc.material == "steel":
        return STEEL
    if sc.material in ALLOYS:
        return ALLOYS[sc.material]
    rng = np.random.default_rng([int(bed_seed), MATERIAL_STREAM])
    nu = float(rng.uniform(*sc.nu_range))
    psi = float(rng.uniform(*sc.psi_range))
    return Material(E=STEEL.E, nu=nu, psi=psi, density=STEEL.density)


def a_star_cap(a_star_max, material):
    """The a* bound of a bed of ``material``: min(a_star_max, critical a* - A_STAR_GAP)."""
    return min(float(a_star_max), critical_a_star(material.nu, material.psi) - A_STAR_GAP)

"""`amfe pack`: generate a powder bed (HCP + scan path) and write it to HDF5.

Lengths on the command line are in mm (radii in um), as in the paper; the
file is in SI (m). The Python equivalent is :func:`amfe.model.bed.generate_bed`
followed by :func:`amfe.io.bedfile.write_bed`.
"""
import math
from decimal import Decimal

import numpy as np

from amfe.cli.options import add_material_args, add_memory_arg, given_material
from amfe.dataset.density import PRECISION, solid_fraction
from amfe.errors import AmfeError
from amfe.io.paths import check_output
from amfe.io.units import length
from amfe.model.bed import check_seed, generate_bed
from amfe.model.bonds import find_bonds
from amfe.model.material import SOURCE_DEFAULT, STEEL, resolve_material
from amfe.model.memory import parse_size
from amfe.model.scales import SCALES
from amfe.model.scanpath import ScanPath
from amfe.model.springs import critical_a_star
from amfe.model.torus import find_periodic_bonds

MM = -3   # decimal exponents of the command-line units
UM = -6


def si(value, exponent):
    """value * 10**exponent, rounded once from the decimal the user typed.

    float(Decimal(repr(x)).scaleb(e)) is the double nearest to e.g. 0.15e-3,
    so ``amfe pack --size 0.15 ...`` builds exactly the bed of
    ``generate_bed((0.15e-3, ...))``; multiplying by 1e-3 can be an ulp off,
    and an ulp in r0 changes every radius.
    """
    return float(Decimal(repr(float(value))).scaleb(exponent))

# Defaults of the paper's figure-2 bed. Kept apart from argparse (whose
# defaults are None) so that a later --scale option can supply its own set.
DEFAULTS = {
    "size": (0.25, 0.25, 0.1),        # mm
    "mean_radius": 12.5,              # um
    "enlargement": (1.05, 1.14),
    "jitter": 0.025,
    "layer_thickness": 0.1,           # mm
    "seed": 0,
    "a_star_max": 0.98,
}

SCAN_OPTIONS = ("track_width", "hatch_spacing", "angle", "layer_rotation",
                "skip_fraction", "skip_length", "offset")
# Options that set the bed's generation parameters: --scale draws them all instead.
GENERATION_OPTIONS = ("size", "mean_radius", "enlargement", "jitter", "layer_thickness",
                      "a_star_max") + SCAN_OPTIONS

MATERIAL_OPTIONS = ("E", "nu", "psi")

# (flag, argparse keywords) of the generation options; all are floats.
BED_ARGS = (
    ("--mean-radius", dict(metavar="UM", help="mean particle radius after enlargement in um "
                                              "(default: 12.5)")),
    ("--enlargement", dict(nargs=2, metavar=("LO", "HI"),
                           help="range of the random radius factors (default: 1.05 1.14)")),
    ("--jitter", dict(metavar="J", help="centre jitter, +/- J R per axis (default: 0.025)")),
    ("--layer-thickness", dict(metavar="MM", help="powder layer thickness in mm, for the scan "
                                                  "path (default: 0.1)")),
    ("--a-star-max", dict(metavar="A", help="largest a* of any bond; radii of bonds above it "
                                            "are shrunk (default: 0.98; must be below the "
                                            "critical 0.9934)")),
)
#: The length options and their unit when bare (a value may carry its own: amfe.io.units).
LENGTH_UNITS = {"--mean-radius": length("um"), "--layer-thickness": length("mm"),
                "--track-width": length("mm"), "--hatch-spacing": length("mm"),
                "--skip-length": length("mm"), "--offset": length("mm")}
SCAN_ARGS = (
    ("--track-width", dict(metavar="MM", help="laser track width in mm")),
    ("--hatch-spacing", dict(metavar="MM", help="centre-to-centre distance of tracks in mm")),
    ("--angle", dict(metavar="DEG", help="track direction in the first powder layer, degrees "
                                         "from +x (default: 0)")),
    ("--layer-rotation", dict(metavar="DEG", help="rotation of the tracks per powder layer in "
                                                  "degrees (default: 67)")),
    ("--skip-fraction", dict(metavar="F", help="probability that a piece of track is skipped, "
                                               "in [0, 1) (default: 0)")),
    ("--skip-length", dict(metavar="MM", help="length of the skipped pieces in mm "
                                              "(default: 0.25)")),
    ("--offset", dict(metavar="MM", help="position of track 0 across the tracks in mm "
                                         "(default: 0)")),
)


def register(subparsers):
    p = subparsers.add_parser(
        "pack", help="generate a powder bed (HCP lattice + laser scan path) as HDF5",
        description="Generate a powder bed: a jittered HCP lattice of enlarged spheres "
                    "(paper section 4), cut by a raster scan path (paper figure 3), with every "
                    "bond's a* kept at or below --a-star-max by shrinking radii. Default: the "
                    "paper's figure-2 bed, 0.25 x 0.25 x 0.1 mm, fully scanned, seed 0. "
                    "Lengths in mm.")
    p.add_argument("-o", "--output", default="bed.h5", metavar="BED.h5",
                   help="output HDF5 file (default: bed.h5)")
    p.add_argument("--size", nargs=3, type=length("mm"), metavar=("LX", "LY", "LZ"),
                   help="box size, mm when bare, or with a unit (0.6mm, 600um) "
                        "(default: 0.25 0.25 0.1)")
    p.add_argument("--seed", type=int, help="random seed, integer >= 0 (default: 0); with "
                   "--scale, the bed seed (a data-set record's /seed)")
    p.add_argument("--scale", type=_scale_name, metavar="SCALE",
                   help="draw every generation parameter from this data-set scale's "
                        "distribution (amfe.model.scales), seeded by --seed: `amfe pack --scale S "
                        "--seed <a record's seed>` regenerates that record's bed exactly; no "
                        "other generation option may be given with it; SCALE is one of "
                        f"{', '.join(SCALES)} or a box scale (amfe dataset --size, e.g. "
                        "box900x900x300um_Ti64)")
    p.add_argument("--periodic", action="store_true",
                   help="make a bed that tiles space in x, y and z (for homogenize --bc "
                        "periodic): the box snaps to whole periods of the HCP lattice (the "
                        "shift is printed), bonds cross the faces by minimum image")
    for flag, kw in BED_ARGS:
        p.add_argument(flag, type=LENGTH_UNITS.get(flag, float), **kw)
    g = p.add_argument_group("scan path (paper figure 3); give at least --track-width and "
                             "--hatch-spacing, otherwise the bed is fully scanned")
    for flag, kw in SCAN_ARGS:
        g.add_argument(flag, type=LENGTH_UNITS.get(flag, float), **kw)
    g.add_argument("--skip-seed", type=int, metavar="S",
                   help="draw the skipped pieces from their own seed S (>= 0), so beds of other "
                        "--seed keep the same holes (default: from --seed, as always)")
    add_material_args(p, "recorded in the bed; the others stay steel's")
    add_memory_arg(p)
    p.set_defaults(func=run)
    return p


def _value(args, name):
    v = getattr(args, name, None)
    return DEFAULTS[name] if v is None else v


def scan_from_args(args):
    """The :class:`ScanPath` the options describe (SI), or None for a fully scanned bed."""
    given = [n for n in SCAN_OPTIONS if getattr(args, n, None) is not None]
    if not given:
        return None
    missing = [n for n in ("track_width", "hatch_spacing") if getattr(args, n) is None]
    if missing:
        raise AmfeError("a scan path needs " + " and ".join("--" + m.replace("_", "-")
                                                          for m in missing)
                        + f" (given: {', '.join('--' + n.replace('_', '-') for n in given)})")
    kw = {"track_width": si(args.track_width, MM), "hatch_spacing": si(args.hatch_spacing, MM)}
    for name, exponent in (("angle", 0), ("layer_rotation", 0), ("skip_fraction", 0),
                           ("skip_length", MM), ("offset", MM)):
        v = getattr(args, name)
        if v is not None:
            kw[name] = si(v, exponent) if exponent else float(v)
    return ScanPath(**kw)


def run(args):
    check_output(args.output)  # before any work: a bad -o costs nothing
    max_memory = None if args.max_memory is None else parse_size(args.max_memory)
    if getattr(args, "scale", None):
        return run_scale(args, max_memory)
    size = tuple(_value(args, "size"))
    if not all(math.isfinite(s) and s > 0 for s in size):
        raise AmfeError("--size must be three positive lengths in mm, got "
                        f"{' '.join(map(str, size))}")
    lo, hi = _value(args, "enlargement")
    if lo > hi:
        raise AmfeError(f"--enlargement LO HI needs LO <= HI, got {lo} {hi}")
    seed = check_seed(_value(args, "seed"), "--seed")
    material, record = resolve_material(given=given_material(args))
    a_star_max = _value(args, "a_star_max")
    crit = critical_a_star(material.nu, material.psi)
    if not 0.0 < a_star_max < crit:
        raise AmfeError(f"--a-star-max must lie in (0, {crit:.6f}), the critical a* for "
                        f"nu={material.nu}, psi={material.psi}; got {a_star_max}")
    scan = scan_from_args(args)

    bed = generate_bed(tuple(si(s, MM) for s in size),
                       mean_radius=si(_value(args, "mean_radius"), UM),
                       enlargement=(lo, hi), jitter=_value(args, "jitter"),
                       layer_thickness=si(_value(args, "layer_thickness"), MM), scan=scan,
                       seed=seed, a_star_max=a_star_max, material=material,
                       periodic=args.periodic, max_memory=max_memory, skip_seed=args.skip_seed)
    report(bed, args.output, f"amfe pack: {size[0]:g} x {size[1]:g} x {size[2]:g} mm, seed "
                             f"{seed}, scan {bed.attrs['scan']}", record)
    return 0


def _scale_name(name):
    """--scale's value if it names a scale (amfe.model.scales.get_scale); argparse's error else."""
    import argparse

    from amfe.model.scales import get_scale
    try:
        return get_scale(name).name
    except AmfeError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_scale(args, max_memory=None):
    """`amfe pack --scale SCALE --seed SEED`: the bed of a data-set record (amfe.model.scales)."""
    from amfe.model.scales import sample_bed_params

    given = [n for n in GENERATION_OPTIONS + MATERIAL_OPTIONS if getattr(args, n, None) is not None]
    if given:
        raise AmfeError(f"--scale {args.scale} draws every generation parameter from the "
                        "scale's distribution; it cannot be combined with "
                        + ", ".join("--" + n.replace("_", "-") for n in given))
    seed = check_seed(0 if args.seed is None else args.seed, "--seed")
    bed = generate_bed(**sample_bed_params(args.scale, seed), periodic=args.periodic,
                       max_memory=max_memory)
    size = [s * 1e3 for s in bed.attrs["size"]]
    report(bed, args.output, f"amfe pack: scale {args.scale}, bed seed {seed}: {size[0]:g} x "
                             f"{size[1]:g} x {size[2]:g} mm, scan {bed.attrs['scan']}")
    return 0


def report(bed, output, title, material=None):
    """Write ``bed`` to ``output`` and print its summary under ``title``.

    material: the record of :func:`amfe.model.material.resolve_material` (default: steel's).
    """
    periodic = "periodic" in bed.attrs
    bonds = find_periodic_bonds(bed.centers, bed.radii, bed.attrs["periodic"])[0] if periodic \
        else find_bonds(bed.centers, bed.radii)
    from amfe.io.bedfile import write_bed  # h5py: only when a bed is written

    write_bed(output, bed)
    a_star_max = bed.attrs["a_star_max"]
    print(title)
    if periodic:
        print(f"  periodic box      {' x '.join(f'{v * 1e3:.6g}' for v in bed.attrs['periodic'])} "
              f"mm, snapped to whole lattice periods by "
              f"{', '.join(f'{v * 1e3:+.4g}' for v in bed.attrs['periodic_snap'])} mm")
    print(f"  particles         {bed.n} (of {bed.attrs['n_lattice']} lattice sites)")
    print(f"  bonds             {len(bonds)}")
    print(f"  mean radius       {bed.radii.mean() * 1e6:.4f} um")
    fraction, error = solid_fraction(bed.centers, bed.radii, np.zeros(3),
                                     np.asarray(bed.attrs["size"], dtype=float))
    print(f"  solid fraction    {fraction:.4f} (the union of the spheres over the box; "
          f"+- {PRECISION:g}; relative density)")
    if len(bonds):
        s = bonds.a_star
        print(f"  a* min/mean/max   {s.min():.4f} / {s.mean():.4f} / {s.max():.4f} "
              f"(max allowed {a_star_max:g})")
    else:
        print("  a* min/mean/max   - (no bonds)")
    print(f"  shrunk particles  {bed.attrs['n_shrunk']} "
          f"(radii reduced so that a* <= {a_star_max:g})")
    m = material or {"E": STEEL.E, "nu": STEEL.nu, "psi": STEEL.psi, "source": SOURCE_DEFAULT}
    print(f"  material          E {m['E'] / 1e9:g} GPa, nu {m['nu']:g}, psi {m['psi']:g} "
          f"({m['source']})")
    print(f"  written           {output}")

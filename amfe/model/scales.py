"""Data-set scales: the distribution a data set's beds are drawn from (issue items 2 and 6).

A record k of a data set with seed S holds the bed whose own seed is
``record_seed(S, k)``; :func:`sample_bed_params` turns (scale, bed seed) into
the keyword arguments of :func:`amfe.model.bed.generate_bed`, so
``amfe pack --scale SCALE --seed <record's seed>`` (= :func:`bed_for`)
regenerates the record's bed bit for bit. Everything here is a pure function
of its arguments: no global state, no dependence on the rank count.

Random streams. The generation parameters are drawn from
``np.random.default_rng([bed_seed, PARAM_STREAM])`` (a SeedSequence of two
words), the bed itself from ``default_rng(bed_seed)`` inside generate_bed:
two independent streams, so the parameters do not correlate with the
lattice's enlargement factors and jitter.

The distribution (every scale; lengths in mm, angles in degrees):

- mean radius 12.5 um, jitter +/- 0.025 R, a* <= 0.98 (paper Table 1 and
  docs/model.md, section 2), three powder layers of 0.1 mm;
- enlargement factors U(1.05, hi), hi ~ U(1.06, 1.14) per bed (the paper's
  range is [1.05, 1.14]; a larger hi gives fatter sintering necks and a
  denser bed; above hi = 1.0967 the generator shrinks a few radii to keep
  a* <= 0.98 and says how many in the bed's n_shrunk);
- track width w ~ U(0.05, 0.15) mm (2 to 6 particle diameters; laser
  tracks in powder-bed fusion are 0.05-0.2 mm);
- scanned fraction c ~ U(0.35, 1.0), hatch spacing h = w / c (c = 1: tracks
  abut, a fully scanned layer; c = 0.35: two thirds of each layer unscanned).
  Drawing c rather than h makes the scanned area, and so the packing
  density, roughly uniform across a data set;
- first-layer angle ~ U(0, 180), layer rotation 67 or 90 (the two usual
  strategies; both make the tracks of consecutive layers cross, so the layers
  of a bed with c < 1 stay bonded to each other: with 0 the unscanned strips of
  all layers line up and the bed falls apart into separate walls, of which
  the homogenization keeps only the largest), hatch offset ~ U(0, h);
- skipped track pieces: none for half the beds, otherwise a skip fraction
  ~ U(0.05, 0.3) with piece length ~ U(0.1, 0.3) mm.

Images: ``amfe.dataset.images.pixelate(bed, cell, layer_thickness, box=[0, size],
spacing=image_spacing)`` with a sample spacing of 2.5 um (R/5, 12 x 12 sample
lines per 0.03 mm cell) instead of pixelate's default R/6 (about 2.1 um, 15 x
15): measured on 12 small beds against a converged reference (spacing
0.75 um), the worst pixel is off by 0.66 % of a cell volume (default: 0.64 %;
docs/model.md, section 7 asks for about 1 %) and the density by 0.03 %, at 0.10 s
per bed instead of 0.14 s.

Packing density, as stored in a data set: the mean of the bed's image, i.e.
the volume fraction of the box [0, Lx] x [0, Ly] x [0, Lz] filled by the
union of the spheres (overlaps counted once; docs/model.md, section 7). With the
ranges above it spans 0.2 to 0.8 on the small scale (300 beds: min 0.22, 5 %
0.28, median 0.49, 95 % 0.74, max 0.78; a fully scanned bed is about 0.78),
spread roughly evenly (``amfe dataset`` prints the histogram).

Scales:

- ``paper``: the paper's 3 mm x 3 mm base, 0.3 mm high (three 0.1 mm layers),
  images 3 x 100 x 100 (cells of 0.03 x 0.03 x 0.1 mm, paper section 6).
  About 290 000 lattice sites before the scan path (a nearly fully scanned
  bed: 257 000 particles, 1.4 million bonds, 65-75 s on one core): for clusters.
- ``small``: 0.6 mm x 0.6 mm x 0.3 mm (the same three layers, a fifth of the side of
  the paper's base), images 3 x 20 x 20 with its cells. Chosen by measurement
  on the 2-core development machine (``run/bench/dataset.py``, 40 beds, the
  machine shared with other jobs): beds of 3 800-10 700 particles (mean
  7 100, 35 000 bonds), 0.02 s generation + 0.06 s image + 1.4 s
  homogenization per bed on one core; 2 400 beds/hour on 1 rank, 3 900 on
  2 ranks, so 2 000 beds take about half an hour on 2 cores. The cells
  and layers are the paper's, so a ``small`` image is a 20 x 20 crop of what
  a ``paper`` image looks like, and 20 x 20 still survives the Custom Net's
  four 2 x 2 poolings; a 0.3 mm base (10 x 10) would not, and 0.9 mm
  (30 x 30) has 2.25x the particles, so about 2.3x the time per bed.
  Tracks of up to 0.15 mm still fit four or more times across the base.
- ``medium``: 1.2 mm x 1.2 mm x 0.3 mm (twice the small side, the same
  layers and cells, images 3 x 40 x 40) with the same scan-path parameter
  ranges as the others: a size between ``small`` and ``paper`` for the
  any-size surrogate (issue 32, item 4). About four times the particles of
  a ``small`` bed (docs/datasets.md gives the measured times).
- box scales (``amfe dataset --size X Y Z``, :mod:`amfe.model.boxscale`): these
  draws at any box, named ``box{X}x{Y}x{Z}um`` (micrometres) with an
  optional material suffix (an alloy, or nu and psi drawn per bed from a
  stream of their own); ``get_scale`` parses the name. ``box600x600x300um``
  makes ``small``'s beds bit for bit. Their images follow the whole-cell rule
  (:attr:`Scale.image_box`): a side that is not whole cells is imaged on its
  whole cells, the remainder strip cropped.
- ``tiny``: for the test suite only: 0.15 mm x 0.15 mm x 0.1 mm (one
  layer, images 1 x 5 x 5, a few hundred particles) and a fifth of its beds
  deliberately empty (the hatch lies outside the box, so generate_bed refuses
  the bed: "the scan path deletes every particle"), which exercises the
  recording of failed beds.
"""
import math

import numpy as np

from amfe.errors import AmfeError
from amfe.model.bed import check_seed, generate_bed
from amfe.model.boxscale import a_star_cap, draw_material, parse_box
from amfe.model.material import STEEL
from amfe.model.scale import MM, SCALES, UM, WHOLE_CELL_TOL, Scale, _whole_cells  # noqa: F401
from amfe.model.scanpath import ScanPath

PARAM_STREAM = 0x5CA1E  # second word of the parameter stream's SeedSequence

# The flat per-record parameters a data set stores (params/<name>), in this order.
PARAM_NAMES = ("enlargement_lo", "enlargement_hi", "track_width", "hatch_spacing", "coverage",
               "angle", "layer_rotation", "offset", "skip_fraction", "skip_length",
               "mean_radius", "jitter", "a_star_max", "empty", "E", "nu", "psi")
PARAM_UNITS = {"enlargement_lo": "-", "enlargement_hi": "-", "track_width": "m",
               "hatch_spacing": "m", "coverage": "- (track width / hatch spacing)",
               "angle": "deg", "layer_rotation": "deg", "offset": "m", "skip_fraction": "-",
               "skip_length": "m", "mean_radius": "m", "jitter": "- (fraction of R)",
               "a_star_max": "-", "empty": "1 if the bed was made empty on purpose (tiny scale)",
               "E": "Pa (the particle material)", "nu": "-", "psi": "-"}


def get_scale(scale):
    """The :class:`Scale` named ``scale`` (or ``scale`` itself); AmfeError for an unknown name."""
    if isinstance(scale, Scale):
        return scale
    if isinstance(scale, str) and scale.startswith("box"):
        return parse_box(scale)
    try:
        return SCALES[scale]
    except (KeyError, TypeError):
        raise AmfeError(f"unknown scale {scale!r}; choose one of {', '.join(SCALES)}") from None


def _check_seed(name, seed):
    return check_seed(seed, name)


def record_seed(dataset_seed, k):
    """The bed seed of record k of the data set with seed ``dataset_seed`` (uint32 as int).

    ``SeedSequence([dataset_seed, k]).generate_state(1)[0]``: a pure function
    of (dataset_seed, k), well mixed, so neighbouring records and neighbouring
    data-set seeds give unrelated beds.
    """
    dataset_seed = _check_seed("data set seed", dataset_seed)
    k = _check_seed("record index", k)
    return int(np.random.SeedSequence([dataset_seed, k]).generate_state(1)[0])


def _uniform(rng, lo_hi):
    lo, hi = lo_hi
    return float(rng.uniform(lo, hi))


def sample_bed_params(scale, bed_seed):
    """generate_bed keyword arguments of the bed with seed ``bed_seed`` in ``scale``.

    Deterministic in (scale, bed_seed); the draws (from
    ``default_rng([bed_seed, PARAM_STREAM])``) are made in a fixed order and
    all of them are always made, so adding a branch never shifts the others.
    Returns {size, mean_radius, enlargement, jitter, layer_thickness, scan,
    seed, a_star_max}; pass it as ``generate_bed(**params)``. See the module
    docstring for the distribution.
    """
    sc = get_scale(scale)
    bed_seed = _check_seed("bed seed", bed_seed)
    rng = np.random.default_rng([bed_seed, PARAM_STREAM])
    hi = _uniform(rng, sc.enlargement_hi)
    width = _uniform(rng, sc.track_width)
    coverage = _uniform(rng, sc.coverage)
    angle = float(rng.uniform(0.0, 180.0))
    rotation = float(sc.layer_rotations[int(rng.integers(len(sc.layer_rotations)))])
    offset_u = float(rng.random())
    skipping = bool(rng.random() < sc.skip_probability)
    skip_fraction = _uniform(rng, sc.skip_fraction)
    skip_length = _uniform(rng, sc.skip_length)
    empty = bool(rng.random() < sc.empty_probability)

    spacing = width / coverage
    scan = ScanPath(track_width=width, hatch_spacing=spacing, angle=angle,
                    layer_rotation=rotation, skip_fraction=skip_fraction if skipping else 0.0,
                    skip_length=skip_length, offset=offset_u * spacing)
    if empty:
        # A hatch whose only tracks lie far outside the box: generate_bed refuses the bed.
        far = 1000.0 * max(sc.size)
        scan = ScanPath(track_width=width, hatch_spacing=4.0 * far, angle=0.0,
                        layer_rotation=0.0, offset=far)
    out = {
        "size": tuple(float(s) for s in sc.size),
        "mean_radius": sc.mean_radius,
        "enlargement": (sc.enlargement_lo, hi),
        "jitter": sc.jitter,
        "layer_thickness": sc.layer_thickness,
        "scan": scan,
        "seed": bed_seed,
        "a_star_max": sc.a_star_max,
    }
    if sc.material != "steel":   # box scales: from a stream of its own, the draws above unchanged
        out["material"] = draw_material(sc, bed_seed)
        out["a_star_max"] = a_star_cap(sc.a_star_max, out["material"])
    return out


def param_record(params):
    """The flat float record of :data:`PARAM_NAMES` for generate_bed kwargs ``params``.

    A fully scanned bed (``scan`` None or full) has coverage 1 and no tracks
    (track width, spacing, angle, rotation, offset NaN).
    """
    scan = params.get("scan")
    mat = params.get("material", STEEL)
    lo, hi = params["enlargement"]
    rec = dict.fromkeys(PARAM_NAMES, float("nan"))
    rec.update(enlargement_lo=float(lo), enlargement_hi=float(hi),
               mean_radius=float(params["mean_radius"]), jitter=float(params["jitter"]),
               a_star_max=float(params["a_star_max"]), skip_fraction=0.0, coverage=1.0,
               E=mat.E, nu=mat.nu, psi=mat.psi)
    if scan is not None and not scan.is_full:
        far = scan.offset > 10.0 * max(params["size"])
        rec.update(track_width=scan.track_width, hatch_spacing=scan.hatch_spacing,
                   coverage=scan.track_width / scan.hatch_spacing, angle=scan.angle,
                   layer_rotation=scan.layer_rotation, offset=scan.offset,
                   skip_fraction=scan.skip_fraction, skip_length=scan.skip_length,
                   empty=1.0 if far else 0.0)
    if math.isnan(rec["empty"]):
        rec["empty"] = 0.0
    return {k: float(v) for k, v in rec.items()}


def bed_for(scale, bed_seed):
    """The bed with seed ``bed_seed`` of ``scale``: generate_bed(**sample_bed_params(...))."""
    return generate_bed(**sample_bed_params(scale, bed_seed))

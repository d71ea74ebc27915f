"""The checked parameters of :func:`amfe.model.bed.generate_bed`: :class:`BedParams`.

``generate_bed`` keeps its keyword options for users and builds one BedParams from
them at once, so that every value is checked in one place, before any work (the
ranges of docs/model.md, section 2).
"""
import math
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError
from amfe.model.material import STEEL, Material
from amfe.model.options import check_flag, check_max_memory
from amfe.model.scanpath import ScanPath
from amfe.model.springs import critical_a_star

SEED_LIMIT = 2**64
"""Seeds lie in [0, 2**64): one word of numpy's SeedSequence, and what an HDF5
attribute (uint64) can hold, so every bed's seed can be written with it."""


def check_seed(seed, name="seed"):
    """``seed`` as an int if it is an integer in [0, 2**64), else AmfeError."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise AmfeError(f"{name} must be an integer in [0, 2**64), got {type(seed).__name__} "
                        f"{seed!r}")
    if not 0 <= int(seed) < SEED_LIMIT:
        raise AmfeError(f"{name} must lie in [0, 2**64) = [0, {SEED_LIMIT - 1}], got {seed}")
    return int(seed)


def _check_number(name, value, lo=None, hi=None, lo_open=False, hi_open=False, unit=""):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise AmfeError(f"{name} must be a number, got {value!r}") from None
    bad = not math.isfinite(v)
    if lo is not None:
        bad |= (v <= lo) if lo_open else (v < lo)
    if hi is not None:
        bad |= (v >= hi) if hi_open else (v > hi)
    if bad:
        rng = ("(" if lo_open else "[") + f"{lo if lo is not None else '-inf'}, " \
            + f"{hi if hi is not None else 'inf'}" + (")" if hi_open else "]")
        raise AmfeError(f"{name} must be finite and lie in {rng}{unit}, got {value!r}")
    return v


@dataclass(frozen=True)
class BedParams:
    """:func:`~amfe.model.bed.generate_bed`'s arguments, checked and normalised when made.

    size (3 floats) [m], mean_radius [m], enlargement (lo, hi), jitter, layer_thickness
    [m], scan (ScanPath or None), seed (int), a_star_max, material, periodic (bool),
    offset, max_memory [bytes] or None, skip_seed (int or None); a_star_critical: the
    material's critical a*. The meaning and ranges of each: generate_bed.
    """

    size: tuple
    mean_radius: float = 12.5e-6
    enlargement: tuple = (1.05, 1.14)
    jitter: float = 0.025
    layer_thickness: float = 100e-6
    scan: ScanPath = None
    seed: int = 0
    a_star_max: float = 0.98
    material: Material = STEEL
    periodic: bool = False
    offset: object = None
    max_memory: float = None
    skip_seed: int = None

    def __post_init__(self):
        size, mean_radius, enlargement = self.size, self.mean_radius, self.enlargement
        jitter, layer_thickness, seed = self.jitter, self.layer_thickness, self.seed
        skip_seed, material, a_star_max, scan = (self.skip_seed, self.material,
                                                 self.a_star_max, self.scan)
        try:
            size = tuple(float(s) for s in size)
        except (TypeError, ValueError):
            raise AmfeError(f"size must be three lengths (Lx, Ly, Lz) in m, got {size!r}") from None
        if len(size) != 3 or not all(math.isfinite(s) and s > 0 for s in size):
            raise AmfeError("size must be three positive finite lengths (Lx, Ly, Lz) in m, got "
                            f"{size}")
        mean_radius = _check_number("mean radius", mean_radius, lo=0.0, lo_open=True, unit=" m")
        try:
            lo_f, hi_f = (float(e) for e in enlargement)
        except (TypeError, ValueError):
            raise AmfeError("enlargement must be two factors (lo, hi), got "
                            f"{enlargement!r}") from None
        if not (math.isfinite(lo_f) and math.isfinite(hi_f)
                and 1.0 <= lo_f <= hi_f < math.sqrt(2.0)):
            raise AmfeError(f"enlargement must satisfy 1 <= lo <= hi < sqrt(2) = 1.414, got "
                            f"lo={lo_f}, hi={hi_f} (below 1 the particles do not touch; from "
                            "sqrt(2) on second lattice neighbours overlap)")
        jitter = _check_number("jitter", jitter, lo=0.0, hi=0.5, hi_open=True,
                               unit=" (fraction of R)")
        layer_thickness = _check_number("powder layer thickness", layer_thickness, lo=0.0,
                                        lo_open=True, unit=" m")
        seed = check_seed(seed)
        if skip_seed is not None:
            skip_seed = check_seed(skip_seed, "skip_seed")
        if not isinstance(material, Material):
            raise AmfeError("material must be an amfe.model.material.Material, got "
                            f"{type(material).__name__}")
        crit = critical_a_star(material.nu, material.psi)
        a_star_max = _check_number("a* max", a_star_max, lo=0.0, hi=crit, lo_open=True,
                                   hi_open=True,
                                   unit=f" (the critical a* is {crit:.6f} for nu={material.nu}, "
                                        f"psi={material.psi})")
        if scan is not None and not isinstance(scan, ScanPath):
            raise AmfeError("scan must be an amfe.model.scanpath.ScanPath or None, got "
                            f"{type(scan).__name__}")
        offset = self.offset
        if offset is not None:
            try:
                offset = np.asarray(offset, dtype=float)
            except (TypeError, ValueError):
                offset = None
            if offset is None or offset.shape != (3,) or not np.isfinite(offset).all():
                raise AmfeError(f"offset must be three finite lengths in m (or None), got "
                                f"{self.offset!r}")
        checked = dict(size=size, offset=offset, mean_radius=mean_radius, enlargement=(lo_f, hi_f),
                       jitter=jitter, layer_thickness=layer_thickness, seed=seed,
                       skip_seed=skip_seed, a_star_max=a_star_max,
                       periodic=check_flag("periodic", self.periodic),
                       max_memory=check_max_memory(self.max_memory))
        for name, value in checked.items():  # frozen: set the normalised values once
            object.__setattr__(self, name, value)

    @property
    def a_star_critical(self):
        """The critical a* of the material (paper eq. 1's k_n pole)."""
        return critical_a_star(self.material.nu, self.material.psi)

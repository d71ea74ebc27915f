"""Raster scan paths of the laser (paper figure 3), vectorised numpy.

A powder bed is built in powder layers of thickness ``layer_thickness`` (z).
In each powder layer the laser scans parallel straight tracks (hatch lines) of
width ``track_width``; only the particles it melts stay in the part. Particles
outside every track, or inside a skipped piece of a track, are deleted by the
generator (:func:`amfe.model.bed.generate_bed`). Varying the hatch across a data set
varies the packing density.

Geometry (all lengths in m, angles in degrees, x-y plane of the bed, origin at
the bed's corner (0, 0)). In powder layer p (p = floor(z / layer_thickness),
counted from z = 0) the tracks run along the unit vector
t = (cos theta_p, sin theta_p), with theta_p = angle + p * layer_rotation
measured counter-clockwise from +x. With n = (-sin theta_p, cos theta_p) the
in-plane normal, a point x has normal coordinate v = n . x and track coordinate
u = t . x. Track k's centre line is v = offset + k * hatch_spacing (k any
integer), so for angle 0 the lines are y = offset + k h, and for angle 90 they
are x = -(offset + k h). A point belongs to track k if
|v - offset - k h| <= track_width / 2 (boundary included).

Skipped segments: each track is cut into pieces of length ``skip_length`` at
u = m * skip_length (m integer); each piece (p, k, m) is left unscanned with
probability ``skip_fraction``, drawn from the caller's numpy Generator. Where
tracks overlap (hatch_spacing < track_width) a point is kept if any track that
covers it is scanned there.
"""
import math
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError


@dataclass(frozen=True)
class ScanPath:
    """A raster hatch; see the module docstring for the geometry.

    track_width: width of a melted track [m] (> 0).
    hatch_spacing: centre-to-centre distance of neighbouring tracks [m] (> 0);
        spacing > width leaves unscanned strips, spacing < width overlaps tracks.
    angle: direction of the tracks in the first powder layer [deg], from +x.
    layer_rotation: added to the angle per powder layer [deg] (67 and 90 are
        common in laser powder-bed fusion).
    skip_fraction: probability in [0, 1) that a piece of track is not scanned.
    skip_length: length of those pieces along the track [m] (> 0).
    offset: phase of the hatch: the normal coordinate of track 0 [m].
    """

    track_width: float
    hatch_spacing: float
    angle: float = 0.0
    layer_rotation: float = 67.0
    skip_fraction: float = 0.0
    skip_length: float = 250e-6
    offset: float = 0.0

    def __post_init__(self):
        for name in ("track_width", "hatch_spacing", "angle", "layer_rotation",
                     "skip_fraction", "skip_length", "offset"):
            value = getattr(self, name)
            try:
                ok = math.isfinite(float(value))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise AmfeError(f"scan path: {name} must be a finite number, got {value!r}")
        if not self.track_width > 0:
            raise AmfeError(f"scan path: track width must be positive, got {self.track_width} m")
        if not self.hatch_spacing > 0:
            raise AmfeError("scan path: hatch spacing must be positive, got "
                            f"{self.hatch_spacing} m")
        if not 0.0 <= self.skip_fraction < 1.0:
            raise AmfeError("scan path: skip fraction must lie in [0, 1), got "
                            f"{self.skip_fraction}")
        if not self.skip_length > 0:
            raise AmfeError(f"scan path: skip length must be positive, got {self.skip_length} m")

    @classmethod
    def full(cls) -> "ScanPath":
        """A path that scans every point: abutting tracks (width == spacing), no skips."""
        return cls(track_width=1.0, hatch_spacing=1.0, angle=0.0, layer_rotation=0.0)

    @property
    def is_full(self) -> bool:
        """True when the tracks cover the whole plane and nothing is skipped."""
        return self.skip_fraction == 0.0 and self.track_width >= self.hatch_spacing

    def as_attrs(self) -> dict:
        """Flat dict of the parameters (SI units, degrees) for bed file attributes."""
        return {
            "scan_track_width": float(self.track_width),
            "scan_hatch_spacing": float(self.hatch_spacing),
            "scan_angle": float(self.angle),
            "scan_layer_rotation": float(self.layer_rotation),
            "scan_skip_fraction": float(self.skip_fraction),
            "scan_skip_length": float(self.skip_length),
            "scan_offset": float(self.offset),
        }


def n_powder_layers(height, layer_thickness):
    """Number of powder layers in a bed of the given height [m] (at least 1).

    A height that is a whole number of layers up to round-off (0.3 mm / 0.1 mm)
    gives that number, not one more.
    """
    return max(1, int(math.ceil(height / layer_thickness - 1e-9)))


def scanned_mask(centers, size, layer_thickness, scan, rng=None):
    """Boolean (N,) mask of the particles the laser melts (True = keep).

    centers: (N,3) particle centres [m] in the box [0, Lx] x [0, Ly] x [0, Lz];
    size: (Lx, Ly, Lz) [m]; layer_thickness: powder layer thickness [m];
    scan: a :class:`ScanPath`, or None for a fully scanned bed; rng: a numpy
    Generator, needed only when scan.skip_fraction > 0.

    The skip draws are a function of the box, the path and the rng state only
    (one (tracks, pieces) array per powder layer, layers in order, drawn even
    for layers that hold no particle), so the same arguments give the same
    mask. Nothing is drawn when skip_fraction is 0 or the path is full.
    Centres a round-off outside the box are counted in the nearest layer.
    """
    centers = np.asarray(centers, dtype=float)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise AmfeError(f"particle centres must have shape (N, 3), got {centers.shape}")
    n = centers.shape[0]
    if scan is None or scan.is_full:
        return np.ones(n, dtype=bool)
    Lx, Ly, Lz = (float(s) for s in size)
    if not layer_thickness > 0:
        raise AmfeError(f"powder layer thickness must be positive, got {layer_thickness} m")
    skipping = scan.skip_fraction > 0.0
    if skipping and rng is None:
        raise AmfeError("scan path with skipped segments needs a random generator (rng)")

    w2, h, off = 0.5 * scan.track_width, scan.hatch_spacing, scan.offset
    n_layers = n_powder_layers(Lz, layer_thickness)
    layer = np.clip(np.floor(centers[:, 2] / layer_thickness), 0, n_layers - 1).astype(np.int64)
    corners = np.array([[0.0, 0.0], [Lx, 0.0], [0.0, Ly], [Lx, Ly]])
    # Tracks farther than this many spacings from the nearest line can still
    # cover a point when they overlap (w > h): test all of them.
    reach = int(math.ceil(w2 / h))
    keep = np.zeros(n, dtype=bool)
    for p in range(n_layers):
        theta = math.radians(scan.angle + p * scan.layer_rotation)
        c, s = math.cos(theta), math.sin(theta)
        sel = np.flatnonzero(layer == p)
        x, y = centers[sel, 0], centers[sel, 1]
        v = -s * x + c * y
        u = c * x + s * y
        if skipping:
            # The tracks and pieces that can touch the box in this layer.
            vc = -s * corners[:, 0] + c * corners[:, 1]
            uc = c * corners[:, 0] + s * corners[:, 1]
            k_lo = math.floor((vc.min() - off - w2) / h) - 1
            k_hi = math.ceil((vc.max() - off + w2) / h) + 1
            m_lo = math.floor(uc.min() / scan.skip_length) - 1
            m_hi = math.floor(uc.max() / scan.skip_length) + 1
            skipped = rng.random((k_hi - k_lo + 1, m_hi - m_lo + 1)) < scan.skip_fraction
            m = np.clip(np.floor(u / scan.skip_length).astype(np.int64) - m_lo, 0, m_hi - m_lo)
        nearest = np.rint((v - off) / h).astype(np.int64)
        on_any = np.zeros(sel.size, dtype=bool)
        for dk in range(-reach, reach + 1):
            k = nearest + dk
            on = np.abs(v - off - k * h) <= w2
            if skipping:
                on &= ~skipped[np.clip(k - k_lo, 0, k_hi - k_lo), m]
            on_any |= on
        keep[sel] = on_any
    return keep

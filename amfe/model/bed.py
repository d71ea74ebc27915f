"""Powder beds: the :class:`Bed` container and the HCP generator (docs/model.md, section 2).

The generator follows the paper's section 4: a close-packed lattice of equal
spheres of base radius r0, every radius enlarged by a random factor (so that
neighbours overlap and sinter into bonds), every centre jittered, then the
particles outside the laser's scan path deleted. One rule is added so that
every bed it emits is valid for the springs of paper eqs. 1-4: bonds past a
stated a*_max are removed by shrinking radii (:func:`limit_a_star`).
"""
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.model.bedparams import SEED_LIMIT, BedParams, check_seed  # noqa: F401 - re-exported
from amfe.model.bonds import find_bonds, validate_particles
from amfe.model.material import STEEL, Material, material_from_attrs
from amfe.model.memory import check_memory, generation_bytes, lattice_counts
from amfe.model.scanpath import ScanPath, scanned_mask
from amfe.model.torus import find_periodic_bonds, periodic_hcp_lattice, snap_box, wrap
from amfe.version import __version__

SQRT3 = math.sqrt(3.0)


@dataclass(eq=False)
class Bed:
    """N spherical particles.

    centers: (N,3) float64 particle centres [m]; radii: (N,) float64 radii [m];
    attrs: material and generation parameters (str, bool, int, float, or small
    numeric lists), SI units; see :func:`generate_bed` for the keys it writes.
    The arrays are the bed's own read-only copies, checked once: make a new Bed to
    change them.
    """

    centers: np.ndarray
    radii: np.ndarray
    attrs: dict = field(default_factory=dict)

    def __post_init__(self):
        # the one place a bed's arrays are checked: below the face nothing checks them again
        # copied and read-only: a NaN written into the caller's arrays (or these) after the
        # check must not reach the solver (docs/hard_cases.md, issue 45 item 4)
        centers, radii = validate_particles(self.centers, self.radii)
        self.centers, self.radii = np.array(centers, np.float64), np.array(radii, np.float64)
        self.centers.flags.writeable = False
        self.radii.flags.writeable = False
        if not isinstance(self.attrs, Mapping) or not all(isinstance(k, str) for k in self.attrs):
            raise AmfeError(f"Bed attrs must be a dict with str keys, got "
                            f"{type(self.attrs).__name__} {self.attrs!r}"[:300])
        self.attrs = dict(self.attrs)
        for key in ("size", "periodic"):   # the box V is taken from: checked here, not in a solve
            if key in self.attrs:
                _check_box_attr(key, self.attrs[key])

    def __repr__(self) -> str:
        """One line: the count, the radii, the box and its source, the material."""
        n = self.radii.size
        size = self.attrs.get("size")
        if size is not None:
            box, source = np.asarray(size, dtype=float), "recorded size"
        else:
            box = ((self.centers + self.radii[:, None]).max(axis=0)
                   - (self.centers - self.radii[:, None]).min(axis=0))
            source = "spheres' bounding box"
        if "periodic" in self.attrs:
            source += ", periodic"
        try:
            m = self.material()
            material = f"E {m.E / 1e9:g} GPa, nu {m.nu:g}, psi {m.psi:g}"
        except AmfeError as exc:
            material = f"material unreadable: {exc}"
        return (f"Bed({n} particles, mean radius {1e6 * float(self.radii.mean()):.4g} um, box "
                f"{' x '.join(f'{1e3 * v:.4g}' for v in box)} mm ({source}), {material})")

    def __len__(self) -> int:
        return self.radii.size

    @property
    def n(self) -> int:
        """Number of particles."""
        return self.radii.size

    def sphere_volume(self) -> float:
        """Sum of the sphere volumes [m^3]; overlaps are counted twice."""
        return float(np.sum(4.0 / 3.0 * np.pi * self.radii**3))

    def material(self, default: Material = STEEL) -> Material:
        """The particle :class:`Material` recorded in attrs (material_E, ...), else ``default``.

        E, nu and psi must be all present or all absent (AmfeError naming the
        missing ones otherwise); material_density is optional.
        """
        return material_from_attrs(self.attrs, default)


def _check_box_attr(key, value):
    """AmfeError unless attrs[key] is a box: three positive finite lengths [m]."""
    try:
        box = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        box = np.array([np.nan])
    if box.shape != (3,) or not np.all(np.isfinite(box) & (box > 0)):
        raise AmfeError(f"Bed attrs[{key!r}] must be three positive lengths in m (a box), got "
                        f"{value!r}"[:300])


def hcp_lattice(size, r0):
    """(N,3) centres [m] of an ABAB close-packed lattice of spheres of radius r0 in a box.

    Layer A: triangular lattice with x spacing 2 r0, rows sqrt(3) r0 apart in
    y, odd rows shifted by r0 in x. Layer B: the same, shifted by
    (r0, r0/sqrt(3)) to sit over the A triangles' centres. Layers are
    2 r0 sqrt(2/3) apart in z; the lattice origin is (r0, r0, r0). A centre is
    kept if it lies in [r0, L - r0] on every axis (within 1e-9 r0, so that a
    box of a whole number of spacings does not lose its last row to
    round-off). Order: by layer, then row, then x: deterministic.
    """
    Lx, Ly, Lz = (float(s) for s in size)
    dz = 2.0 * r0 * math.sqrt(2.0 / 3.0)
    dy = SQRT3 * r0
    tol = 1e-9 * r0
    # Index ranges generous enough that the shifted rows/layers reach the lower faces.
    ix = np.arange(-2, int(math.ceil(Lx / (2.0 * r0))) + 2)
    iy = np.arange(-2, int(math.ceil(Ly / dy)) + 2)
    iz = np.arange(0, int(math.ceil(Lz / dz)) + 2)
    kz, ky, kx = np.meshgrid(iz, iy, ix, indexing="ij")
    kz, ky, kx = kz.ravel(), ky.ravel(), kx.ravel()
    b_layer = kz % 2
    x = r0 + 2.0 * r0 * kx + r0 * (ky % 2) + r0 * b_layer
    y = r0 + dy * ky + (r0 / SQRT3) * b_layer
    z = r0 + dz * kz
    pts = np.stack([x, y, z], axis=1)
    lo = r0 - tol
    hi = np.array([Lx, Ly, Lz]) - r0 + tol
    inside = np.all((pts >= lo) & (pts <= hi), axis=1)
    return pts[inside]


def pair_a_star(L, Ri, Rj):
    """a* = a / R_eff of pairs at distance L (M,) with radii Ri, Rj (M,).

    The same arithmetic as :func:`amfe.model.bonds.contact_geometry` (Heron form), so
    a value computed here is bit for bit the one find_bonds reports for the
    same L and radii. 0 for pairs that do not overlap.
    """
    heron = (Ri + Rj - L) * (L + Ri - Rj) * (L - Ri + Rj) * (Ri + Rj + L)
    a = np.sqrt(np.maximum(heron, 0.0)) / (2.0 * L)
    return a / (Ri * Rj / (Ri + Rj))


def shrink_factor(L, Ri, Rj, a_star_target, iterations=64):
    """Common factor lam (M,) such that radii lam Ri, lam Rj at distance L give a* = target.

    Vectorised bisection on lam in [L / (Ri + Rj), 1]: a* is 0 at the lower
    end (the spheres just touch) and increases monotonically with lam (a* of a
    pair depends only on L / lam in units of the radii, and decreases as the
    centres separate). Assumes a*(1) > target. Returns the lower end of the
    final bracket, so pair_a_star(L, lam Ri, lam Rj) <= target holds exactly
    in floating point, and lam is within a few ulp of the exact root.
    """
    lo = L / (Ri + Rj)
    hi = np.ones_like(lo)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        above = pair_a_star(L, mid * Ri, mid * Rj) > a_star_target
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return lo


def limit_a_star(centers, radii, a_star_max, max_passes=50, box=None):
    """Shrink radii until every bond has a* <= a_star_max.

    Rule (the generator's a* guarantee, docs/model.md, sections 2 and 5a): find the bonds; for
    each bond with a* > a_star_max compute the common factor lam < 1 that,
    applied to both radii, brings that bond's a* to a_star_max
    (:func:`shrink_factor`); each particle takes the smallest factor over its
    offending bonds; repeat until no bond exceeds a_star_max. Shrinking a
    particle lowers the a* of its other bonds (at fixed L, a* increases with
    each radius wherever a* < 1.3, checked numerically in the tests; the
    monotonicity fails only for deep overlaps with a* > 1.33, beyond anything
    a close packing with enlargement < sqrt(2) and jitter < 0.5 reaches in
    practice), so a pass creates no new offenders and the loop ends after
    one pass plus the checking one; the cap only guards against the unforeseen.

    centers (N,3) [m], radii (N,) [m]; box (3,) [m]: bonds by minimum image on
    this torus (a periodic bed, docs/model.md, section 9). Returns (radii (N,) new array, n_shrunk:
    the number of particles whose radius was reduced, passes: shrinking passes
    made). Raises AmfeError if max_passes passes do not settle.
    """
    radii = np.array(radii, dtype=float)
    shrunk = np.zeros(radii.size, dtype=bool)
    bonds, changed = None, None
    for passes in range(max_passes + 1):
        if box is not None:
            bonds = find_periodic_bonds(centers, radii, box)[0]
        elif bonds is None:
            bonds = find_bonds(centers, radii)
        else:
            # Shrinking only removes bonds, and only a bond with a shrunk particle changes its
            # a*: those are recomputed (pair_a_star is contact_geometry's arithmetic, bit for
            # bit; a pair that no longer overlaps gets 0), the others keep theirs.
            touched = np.flatnonzero(changed[bonds.i] | changed[bonds.j])
            i, j = bonds.i[touched], bonds.j[touched]
            bonds.a_star[touched] = pair_a_star(bonds.length[touched], radii[i], radii[j])
        bad = np.flatnonzero(bonds.a_star > a_star_max)
        if bad.size == 0:
            return radii, int(shrunk.sum()), passes
        if passes == max_passes:
            break
        i, j = bonds.i[bad], bonds.j[bad]
        lam = shrink_factor(bonds.length[bad], radii[i], radii[j], a_star_max)
        factor = np.ones(radii.size)
        np.minimum.at(factor, i, lam)
        np.minimum.at(factor, j, lam)
        changed = factor < 1.0
        radii[changed] = radii[changed] * factor[changed]
        shrunk |= changed
    raise AmfeError(f"could not bring every bond to a* <= {a_star_max} in {max_passes} passes "
                    f"of radius shrinking ({bad.size} bonds still above, max a* "
                    f"{bonds.a_star[bad].max():.6f}); lower the enlargement or the jitter")


def generate_bed(size: tuple[float, float, float] = (250e-6, 250e-6, 100e-6), *,
                 mean_radius: float = 12.5e-6, enlargement: tuple[float, float] = (1.05, 1.14),
                 jitter: float = 0.025, layer_thickness: float = 100e-6,
                 scan: ScanPath | None = None, seed: int = 0, a_star_max: float = 0.98,
                 material: Material = STEEL, periodic: bool = False,
                 offset: tuple[float, float, float] | None = None,
                 max_memory: float | str | None = None, skip_seed: int | None = None) -> Bed:
    """A powder bed on a jittered, enlarged HCP lattice, cut by a scan path.

    size: (Lx, Ly, Lz) of the box [m] (default: the paper's figure-2 bed,
    0.25 mm x 0.25 mm x 0.1 mm); mean_radius: target mean radius after
    enlargement [m]; enlargement: (lo, hi), radius factors drawn uniformly,
    1 <= lo <= hi < sqrt(2) (beyond sqrt(2) second lattice neighbours overlap);
    jitter: each centre moves uniformly by +/- jitter R_i per axis, 0 <= jitter
    < 0.5 (0.025: the paper's cubic box of side 2.05 R_i); layer_thickness:
    powder layer thickness for the scan path [m]; scan: :class:`ScanPath` or
    None (fully scanned); seed: int, 0 <= seed < 2**64 (the range of the
    generator's seed words that a bed file's attribute can hold); a_star_max: bound on every bond's
    a* (0 < a_star_max < critical a* of the material, 0.9934 for steel);
    material: :class:`Material` (recorded in attrs and used for the critical a*);
    periodic: make a bed that tiles space (docs/model.md, section 9): the box
    is snapped to whole lattice periods (:func:`amfe.model.torus.snap_box`),
    the sites are the infinite lattice's in [0, L), centres are wrapped into
    the box after the jitter, bonds in step 5 are found by minimum image;
    offset (3,) [m], periodic only: shift the whole lattice (default 0).
    The random numbers are drawn in the same order as for a non-periodic bed.
    max_memory: bytes the generation may take (default: half the machine's
    memory); a larger estimate (:mod:`amfe.model.memory`) is refused before
    anything is allocated.
    skip_seed: opt-in; an int seed draws the skipped scan pieces from their own
    ``default_rng(skip_seed)`` instead of the bed's generator, so beds of other
    seeds keep the same holes while their enlargements and jitter change (the
    label-noise study of docs/surrogate.md). None (default): today's beds, bit
    for bit.

    Steps, all random numbers from one ``np.random.default_rng(seed)`` drawn
    in this order, so the same arguments give the same bed bit for bit:

    1. r0 = mean_radius / mean(enlargement); lattice = :func:`hcp_lattice`.
    2. factors f ~ U(lo, hi), one per lattice site; R = r0 f.
    3. jitter ~ U(-1, 1) per site and axis, times jitter R_i.
    4. scan-path deletion (:func:`amfe.model.scanpath.scanned_mask` on the jittered
       centres; it draws the skipped segments).
    5. a* guarantee (:func:`limit_a_star`): while a bond has a* > a_star_max,
       both radii of each offending pair shrink by the common factor that puts
       that pair at a* = a_star_max exactly, each particle taking its smallest
       factor. No random numbers. Worst case with jitter 0.025: two
       particles of radius f_max r0 on an inter-layer bond pushed together
       by the jitter along it (1-norm of the bond direction 1.605); this
       pair stays at a* <= 0.98 for f_max <= 1.0967 and below the critical
       0.99339 for f_max <= 1.1013, for any seed. The paper's 1.14 shrinks
       about 8 % of the particles, by 0.5 % on average and under 3 %
       (attrs['n_shrunk'] says how many).

    Returns a :class:`Bed`, particles in lattice order. attrs (SI units):
    generator='amfe.hcp', amfe_version, size, mean_radius, r0, enlargement,
    jitter, layer_thickness, seed, scan ('full' or 'raster') and scan_* (the
    :class:`ScanPath` fields, when raster), material_E, material_nu,
    material_psi, material_density, a_star_max, a_star_critical, n_lattice
    (sites before the scan path), n_scanned_out (deleted by it), n_shrunk,
    shrink_passes; a periodic bed adds periodic = [Lx, Ly, Lz] (the snapped
    box, also its size), periodic_requested, periodic_snap (L - requested),
    periodic_periods, periodic_offset.
    """
    p = BedParams(size, mean_radius, enlargement, jitter, layer_thickness, scan, seed,
                  a_star_max, material, periodic, offset, max_memory, skip_seed)  # checked
    size, mean_radius, (lo_f, hi_f), jitter = p.size, p.mean_radius, p.enlargement, p.jitter
    layer_thickness, scan, seed, a_star_max = p.layer_thickness, p.scan, p.seed, p.a_star_max
    material, skip_seed, periodic, max_memory = p.material, p.skip_seed, p.periodic, p.max_memory
    offset = p.offset
    r0 = mean_radius / (0.5 * (lo_f + hi_f))
    n_sites = lattice_counts(size, r0)[1]
    check_memory(generation_bytes(size, r0), max_memory,
                 f"generating a bed of {size[0]:.4g} x {size[1]:.4g} x {size[2]:.4g} m "
                 f"(about {float(n_sites):.3g} lattice sites of radius {r0:.4g} m)")
    if periodic:
        requested, offset = size, np.zeros(3) if offset is None else np.asarray(offset, float)
        box, counts, moved = snap_box(size, r0, hi_f * r0)
        size = tuple(box.tolist())
        lattice = periodic_hcp_lattice(counts, r0, offset)
    elif offset is not None:
        raise AmfeError("offset shifts the lattice of a periodic bed only: pass periodic=True")
    else:
        lattice = hcp_lattice(size, r0)
    n_lattice = lattice.shape[0]
    if n_lattice == 0:
        raise AmfeError(f"the box {tuple(s * 1e3 for s in size)} mm holds no particle: every side "
                        f"must be at least one diameter 2 r0 = {2e3 * r0:.4g} mm")

    rng = np.random.default_rng(seed)
    radii = r0 * rng.uniform(lo_f, hi_f, n_lattice)
    centers = lattice + rng.uniform(-1.0, 1.0, (n_lattice, 3)) * (jitter * radii)[:, None]
    if periodic:
        centers = wrap(centers, box)

    skip_rng = rng if skip_seed is None else np.random.default_rng(int(skip_seed))
    keep = scanned_mask(centers, size, layer_thickness, scan, skip_rng)
    if not keep.any():
        raise AmfeError("the scan path deletes every particle of the bed: widen the tracks, "
                        "narrow the hatch spacing or lower the skip fraction")
    centers, radii = centers[keep], radii[keep]

    radii, n_shrunk, passes = limit_a_star(centers, radii, a_star_max,
                                           box=box if periodic else None)

    attrs = _attrs(p, size, r0, n_lattice, centers.shape[0], n_shrunk, passes)
    if periodic:
        attrs.update({"periodic": list(size), "periodic_requested": list(requested),
                      "periodic_snap": moved.tolist(), "periodic_periods": counts.tolist(),
                      "periodic_offset": offset.tolist()})
    return Bed(centers=centers, radii=radii, attrs=attrs)


def _attrs(p, size, r0, n_lattice, n_kept, n_shrunk, passes):
    """The attrs of a generated bed (see :func:`generate_bed`); p: its :class:`BedParams`,
    size: the box (snapped, for a periodic bed) [m]."""
    mean_radius, (lo_f, hi_f), jitter = p.mean_radius, p.enlargement, p.jitter
    layer_thickness, scan, seed, a_star_max = p.layer_thickness, p.scan, p.seed, p.a_star_max
    material, skip_seed, crit = p.material, p.skip_seed, p.a_star_critical
    attrs = {
        "generator": "amfe.hcp",
        "amfe_version": __version__,
        "units": "SI (m, Pa, kg/m^3); angles in degrees",
        "size": list(size),
        "mean_radius": mean_radius,
        "r0": r0,
        "enlargement": [lo_f, hi_f],
        "jitter": jitter,
        "layer_thickness": layer_thickness,
        "seed": seed,
        "scan": "full" if scan is None or scan.is_full else "raster",
    }
    if scan is not None and not scan.is_full:
        attrs.update(scan.as_attrs())
    if skip_seed is not None:
        attrs["skip_seed"] = int(skip_seed)
    attrs.update({
        "material_E": float(material.E),
        "material_nu": float(material.nu),
        "material_psi": float(material.psi),
        "material_density": float(material.density),
        "a_star_max": a_star_max,
        "a_star_critical": crit,
        "n_lattice": int(n_lattice),
        "n_scanned_out": int(n_lattice - n_kept),
        "n_shrunk": n_shrunk,
        "shrink_passes": passes,
    })
    return attrs

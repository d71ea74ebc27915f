"""The load-carrying space frame of a bed, non-dimensionalised (docs/model.md, sections 1 and 5).

Only what carries load is modelled: the bond graph's components that the
boundary condition loads and holds (:mod:`amfe.model.carrying`) are kept and
every other particle is dropped before anything else. V is the bed's own box
(:func:`amfe.model.carrying.bed_box`), not the hull of the kept centres.
Lengths are divided by the mean input radius ``length_scale`` and forces by
``force_scale = E * length_scale**2``; then k_n, k_t and kappa_n, kappa_t are
all O(1) instead of ~1e5 N/m against ~1e-5 N m, which keeps the global matrix
well scaled for the iterative solver and makes results independent of the
caller's unit system.
"""
import time
from contextvars import ContextVar
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.model.bonds import Bonds, bond_springs, contact_geometry, find_pairs
from amfe.model.carrying import component_labels, periodic_carrying, removed_report
from amfe.model.conditions import get_condition
from amfe.model.material import STEEL, Material
from amfe.model.torus import check_box, find_periodic_pairs, wrap
from amfe.model.volumebox import placed_box


@dataclass
class Frame:
    """A connected bonded frame in non-dimensional units.

    centers (n,3), radii (n,): kept particles, lengths / length_scale, in
    locality (Morton) order; kept (n,): their indices in the input bed;
    bonds: :class:`amfe.model.bonds.Bonds` between kept particles (renumbered);
    k_n, k_t (M,) [force_scale / length_scale]; kappa_n, kappa_t (M,)
    [force_scale * length_scale]; n_input: particles in the input;
    n_capped: bonds whose a* was capped; length_scale [m]; force_scale [N].
    A periodic frame (docs/model.md, section 9) also has box (3,) [length_scale]:
    the periods, and shift (M,3) int: bond b joins i to the image of j at
    x_j + shift_b * box; both are None otherwise. origin (3,) [m]: where the
    frame's zero lies in the input's coordinates (:func:`frame_origin`):
    input centre = centers * length_scale + origin; size (3,) [length_scale]: the
    bed's box, volume = its product [length_scale^3], V of every average;
    parts (n,) int: the kept component (0..k-1) of each particle; removed: the
    report of :func:`amfe.model.carrying.removed_report`; box_note: why the
    recorded size was not V's box (None when it was, or there was none);
    box_source: where V's box came from (:data:`amfe.model.carrying.BOX_SOURCES`);
    box_lo (3,) [m]: the lower corner of V's box in the input's coordinates
    (:func:`amfe.model.volumebox.placed_box`; a periodic box's is ``origin``).
    """

    centers: np.ndarray
    radii: np.ndarray
    kept: np.ndarray
    bonds: Bonds
    k_n: np.ndarray
    k_t: np.ndarray
    kappa_n: np.ndarray
    kappa_t: np.ndarray
    n_input: int
    n_capped: int
    length_scale: float
    force_scale: float
    material: Material
    box: np.ndarray = None
    shift: np.ndarray = None
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    size: np.ndarray = None
    parts: np.ndarray = None
    removed: dict = None
    box_note: str = None
    box_source: str = None
    box_lo: np.ndarray = None

    @property
    def volume(self):
        """V [length_scale^3]: the bed's box (docs/model.md, section 5)."""
        return float(np.prod(self.size))

    @property
    def n_particles(self):
        return self.centers.shape[0]

    @property
    def n_removed(self):
        return self.n_input - self.n_particles

    @property
    def stress_scale(self):
        """Pa per non-dimensional stress unit (= E)."""
        return self.force_scale / self.length_scale**2


def morton_order(points, bits=10):
    """Permutation (n,) sorting points along a Z-order curve (locality for row blocks)."""
    lo = points.min(axis=0)
    span = np.maximum(points.max(axis=0) - lo, 1e-300)
    q = np.minimum(((points - lo) / span * (2**bits - 1)).astype(np.uint64), 2**bits - 1)
    code = np.zeros(points.shape[0], np.uint64)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + axis)
    return np.argsort(code, kind="stable")


def _check_spans_volume(x, mean_radius):
    """AmfeError when the centres x (n,3) lie within one mean radius of a plane or a line.

    The axis-aligned case is caught just before (its message names the axis);
    this catches tilted sheets and chains (a straight chain along (1, 1, 1)),
    whose KUBC problem is singular, before any solve. The thinnest direction
    is the principal axis of least spread.
    """
    d = x - x.mean(axis=0)
    normal = np.linalg.eigh(d.T @ d)[1][:, 0]
    width = float(np.ptp(d @ normal)) / mean_radius
    if width < 1.0:
        raise AmfeError(
            f"the load-carrying particles form a sheet or a line: their centres span only "
            f"{width:.3g} mean radii across the direction ({normal[0]:.3f}, {normal[1]:.3f}, "
            f"{normal[2]:.3f}), less than one radius, so they span no volume to average over; "
            "a bed needs at least two particle layers in every direction")


#: A callable given :func:`build_frame`'s progress lines, or None (the default: none are made);
#: set for one build by the solver layer on long solves (a context variable: no argument to
#: pass through, and each thread or task has its own).
FRAME_LOG = ContextVar("FRAME_LOG", default=None)


def build_frame(centers, radii, material: Material = STEEL, a_star_cap=None, nondimensional=True,
                box=None, bc="kubc", size=None):
    """The load-carrying, non-dimensionalised frame of a bed under condition ``bc``.

    centers (N,3) [m], radii (N,) [m]: a :class:`~amfe.model.bed.Bed`'s arrays, checked
    when it was made. Raises AmfeError for degenerate contacts, a bed without bonds, a
    load-carrying part too small to span a volume, or (unless ``a_star_cap`` is given)
    bonds at or past the critical a* (see :func:`amfe.model.bonds.bond_springs`).
    ``nondimensional=False`` keeps SI units (length_scale = force_scale = 1):
    only for showing what the scaling buys. ``box`` (3,) [m]: the bed is
    periodic with these periods (docs/model.md, section 9): bonds by minimum
    image, the components that wind round the torus, which together must wrap
    round it in x, y and z (else no macro-stress along some axis: an error).
    bc: a condition of :mod:`amfe.model.conditions`, whose carrying rule picks the
    load-carrying components (:mod:`amfe.model.carrying`; mixed: one held piece at most).
    size (3,) [m]: the bed's recorded box (attrs ``size``); V is its volume, else that of the
    load-carrying spheres' bounding box (a periodic bed: the periods); a
    :class:`amfe.model.carrying.GivenBox` is V's box as the user states it, checked
    against the kept centres (:func:`amfe.model.carrying.box_rule`, the one box rule).
    Progress lines as the contacts are found and the springs evaluated go to
    :data:`FRAME_LOG`'s callable, if one is set (long solves, :mod:`amfe.solvers.progress`).
    """
    log = FRAME_LOG.get() or (lambda line: None)
    t0 = time.perf_counter()
    centers, radii = np.asarray(centers, float), np.asarray(radii, float)  # checked (a Bed's)
    n_input = centers.shape[0]
    length = float(radii.mean()) if nondimensional else 1.0
    origin = np.zeros(3) if box is not None else frame_origin(centers)
    x = (centers - origin) / length
    r = radii / length

    if box is None:
        i, j = find_pairs(x, r)
        shift = L = None
    else:
        L = check_box(box, radii) / length
        x = wrap(x, L)
        i, j, shift = find_periodic_pairs(x, r, L)
    log(f"frame: {i.size} contacts found in {time.perf_counter() - t0:.2f} s")
    if i.size == 0:
        raise AmfeError(f"the bed has no bonds: none of its {n_input} particles overlap "
                        "(bonded means |x_j - x_i| < R_i + R_j)")
    contact_geometry(x, r, i, j, None if box is None else shift * L)  # errors anywhere in the bed
    labels = component_labels(n_input, i, j)
    carrying = get_condition(bc).carrying
    if box is not None and not get_condition(bc).periodic:
        carrying = periodic_carrying   # a torus: what winds round it carries load
    ids = carrying(x, r, i, j, shift, L, labels)
    keep = np.isin(labels, ids)
    kept = np.flatnonzero(keep)
    if kept.size < 4:
        raise AmfeError(f"the load-carrying part of the bed has only {kept.size} particles; "
                        "at least 4 non-coplanar centres are needed to span a volume")
    kept = kept[morton_order(x[kept])]
    parts = np.searchsorted(ids, labels[kept])
    removed = removed_report(x, r, labels, ids, n_input)
    size_f, box_note, box_source, box_lo = L, None, "periodic box", origin  # the periods
    if box is None:                                  # in SI, then in frame units
        box_lo, size_f, box_note, box_source = placed_box(centers - origin, radii, size,
                                                          kept)  # exact (frame_origin)
        size_f, box_lo = size_f / length, box_lo + origin
    new_index = np.full(n_input, -1, np.int64)
    new_index[kept] = np.arange(kept.size)
    both = keep[i]  # a bond lies in the component iff either end does
    bi, bj = new_index[i[both]], new_index[j[both]]
    lo, hi = np.minimum(bi, bj), np.maximum(bi, bj)
    order = np.lexsort((hi, lo))
    if box is not None:  # a reversed bond joins the image at -shift
        shift = np.where((bi > bj)[:, None], -shift[both], shift[both])[order]
    x, r = x[kept], r[kept]
    extent = (x.max(axis=0) - x.min(axis=0)) / r.mean()  # in mean radii
    if extent.min() < 1.0:
        axis = "xyz"[int(np.argmin(extent))]
        raise AmfeError(
            f"the load-carrying particles form a sheet or a line: their centres span only "
            f"{extent.min():.3g} mean radii along {axis}, less than one radius, so they span "
            "no volume to average over; a bed needs at least two particle layers in every "
            "direction")
    _check_spans_volume(x, r.mean())
    bonds = contact_geometry(x, r, lo[order], hi[order], None if box is None else shift * L)
    E = 1.0 if nondimensional else material.E
    unit = Material(E=E, nu=material.nu, psi=material.psi, density=material.density)
    log(f"frame: {kept.size} load-carrying particles; evaluating the springs of {len(bonds)} "
        "bonds")
    t0 = time.perf_counter()
    k_n, k_t, kappa_n, kappa_t, n_capped = bond_springs(bonds, unit, a_star_cap, labels=kept)
    log(f"frame: springs evaluated in {time.perf_counter() - t0:.2f} s")
    return Frame(centers=x, radii=r, kept=kept, bonds=bonds, k_n=k_n, k_t=k_t,
                 kappa_n=kappa_n, kappa_t=kappa_t, n_input=n_input, n_capped=n_capped,
                 length_scale=length, force_scale=material.E / E * length**2, material=material,
                 box=L, shift=shift, size=size_f, parts=parts, removed=removed,
                 box_note=box_note, box_source=box_source, origin=origin, box_lo=box_lo)


FAR = 4.0
"""A bed is built about its own middle along an axis where it lies at least this many of its
own extents from zero (closer, positions near zero lose at most a few bits anyway)."""


def frame_origin(centers):
    """(3,) [m]: the origin the frame is built about, so that centre - origin is exact.

    The constants do not depend on where a bed lies, but float64 arithmetic on
    positions far from zero does (x - x_c, the Bagi sums, the hull): a bed
    translated by 1e7 m moved its constants by 2e-4 that way
    (docs/hard_cases.md). So along an axis where every centre lies at least
    :data:`FAR` extents from zero, the origin is the middle m of the centres'
    range; every centre c then lies in [m/2, 2m] and c - m is exact
    (Sterbenz's lemma): the frame is that of the stored coordinates. Along
    the other axes it is 0, so a bed at or around zero (a generated one, in
    [0, L]) keeps the very numbers of before.
    """
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    near = np.where(lo > 0, lo, np.where(hi < 0, -hi, 0.0))   # the smallest |c| per axis
    far = (near > 0) & (near >= FAR * (hi - lo))
    return np.where(far, lo + (hi - lo) / 2, 0.0)

"""Bond detection and contact geometry (docs/model.md, section 3), vectorised numpy.

Particles i, j are bonded iff L = |x_j - x_i| < R_i + R_j. For each bond the
contact plane sits at distance d_i from centre i and d_j = L - d_i from centre
j; its radius is a, the effective radius R = R_i R_j / (R_i + R_j), a* = a / R.
"""
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError, _list_items
from amfe.model import pairkernel
from amfe.model.material import Material
from amfe.model.springs import A_STAR_MARGIN, critical_a_star, spring_constants

LENGTH_RANGE = (1e-60, 1e60)
"""Radii and coordinates must lie in this range (in the caller's length unit, SI: m):
contact radii go through R^4 (Heron's form), which under- or overflows float64
beyond about 1e-75 and 1e75."""
MAX_REACH = 1e9
"""Centres may lie at most this many mean radii from the origin. The frame is
built about the bed's own middle (:func:`amfe.model.frame.frame_origin`), so
no arithmetic is lost far out; but the stored coordinates themselves carry
only 2.2e-16 x their size, and that rounding moves the constants by about
(2-8)e-16 x the distance in mean radii. Measured on three generated beds
(28-210 particles, Cholesky, moved along x, y, z and the diagonal): at most
4.2e-7 at 1e9 R, 4.5e-6 at 1e10 R, 8.5e-5 at 1e11 R; 1e9 keeps it a
twentieth of the solver's 1e-5 contract (docs/hard_cases.md)."""


def real_array(value, name):
    """``value`` as a float64 array if it holds real numbers; AmfeError otherwise.

    Refuses complex (the imaginary part would be dropped silently), bool,
    str and object arrays, and ragged nested lists. A float64 array is
    returned as it is (no copy).
    """
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise AmfeError(f"{name} must be an array of real numbers: {exc}") from None
    if arr.dtype.kind not in "iuf":
        kind = {"c": "complex numbers (the imaginary part would be lost)", "b": "booleans",
                "U": "strings", "S": "bytes", "O": "Python objects"}.get(arr.dtype.kind, "")
        raise AmfeError(f"{name} must hold real numbers (float64), got dtype {arr.dtype}"
                        + (f": {kind}" if kind else ""))
    return np.asarray(arr, dtype=float)


def check_shapes(centers_shape, radii_shape):
    """AmfeError unless the shapes are (N, 3) and (N,) (checked before reading a file's data)."""
    if len(centers_shape) != 2 or centers_shape[1] != 3:
        raise AmfeError(f"particle centres must have shape (N, 3), got {tuple(centers_shape)}")
    if tuple(radii_shape) != (centers_shape[0],):
        raise AmfeError(f"radii must have shape ({centers_shape[0]},) to match the centres, "
                        f"got {tuple(radii_shape)}")


def validate_particles(centers, radii):
    """Return (centers (N,3), radii (N,)) as float64 arrays, or raise AmfeError.

    Rejects arrays that are not real numbers (complex, bool, str, object),
    wrong shapes, non-finite coordinates, non-finite or non-positive radii,
    and lengths float64 cannot carry through the contact geometry (radii
    outside :data:`LENGTH_RANGE`, centres farther than :data:`MAX_REACH` mean
    radii from the origin), naming the offending particles.
    """
    centers = real_array(centers, "particle centres")
    radii = real_array(radii, "radii")
    check_shapes(centers.shape, radii.shape)
    if centers.shape[0] == 0:
        raise AmfeError("the bed has no particles")
    if not np.isfinite(centers).all():   # the per-particle search only when one is bad
        bad = np.flatnonzero(~np.isfinite(centers).all(axis=1))
        raise AmfeError(f"{bad.size} particles have non-finite centres: particles "
                        f"{_list_items(bad)}")
    bad = np.flatnonzero(~(np.isfinite(radii) & (radii > 0)))
    if bad.size:
        raise AmfeError(f"{bad.size} particles have non-finite or non-positive radii: "
                        + _list_items(f"{k} (R={radii[k]!r})" for k in bad))
    _check_lengths(centers, radii)
    return centers, radii


def _check_lengths(centers, radii):
    lo, hi = LENGTH_RANGE
    bad = np.flatnonzero((radii < lo) | (radii > hi))
    if bad.size:
        raise AmfeError(f"{bad.size} radii lie outside [{lo:g}, {hi:g}] (lengths in m): "
                        + _list_items(f"{k} (R={radii[k]:.3g})" for k in bad)
                        + "; float64 cannot carry such lengths through the contact geometry. "
                        "Check the unit of the bed's lengths")
    with np.errstate(over="ignore"):   # 1e300 / 1e-60: inf, refused below
        a = np.abs(centers)   # max over the 3 columns: 15x faster than max(axis=1)
        reach = np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2]) / radii.mean()
    bad = np.flatnonzero(reach > MAX_REACH)
    if bad.size:
        raise AmfeError(f"{bad.size} centres lie more than {MAX_REACH:g} mean radii from the "
                        "origin, beyond which float64 stores positions to worse than 2e-7 of a "
                        "radius and the constants move by more than 1e-6 with the rounding: "
                        + _list_items(f"{k} ({reach[k]:.3g} mean radii)" for k in bad)
                        + ". Check the coordinates and their unit, or move the bed to the origin")


COINCIDENT = 1e-12
"""Centres closer than this times the larger radius coincide (L = 0 for the contact geometry)."""


def coincident_error(i, j):
    """The AmfeError naming the pairs (i, j) (two (M,) int arrays) of coincident centres."""
    return AmfeError(f"{i.size} pairs of particles have coincident centres: "
                     + _list_items(f"({a}, {b})" for a, b in zip(i, j))
                     + ". Remove the duplicates from the bed.")


def check_coincident(centers, radii):
    """AmfeError if centres coincide, in O(N log N) time and O(N) memory.

    The KD-tree of :func:`find_pairs` would list every pair of a pile of k
    coincident particles (k^2 / 2: 3 000 of them took 12 s and 0.8 GB, 300 000
    never finished) before :func:`contact_geometry` refused the first. Here the
    centres are rounded to a grid of COINCIDENT x the largest radius and sorted
    by cell: each particle whose cell holds an earlier one is paired with the
    first of that cell, and the pair is refused if it passes the exact test of
    :func:`contact_geometry`. A near pair split by a cell boundary is left to
    that test (there are few: a pile of them shares a cell).
    """
    cell = np.floor(centers / (COINCIDENT * float(radii.max())))
    order = np.lexsort(cell.T[::-1])
    c = cell[order]
    same = np.flatnonzero((c[1:] == c[:-1]).all(axis=1)) + 1   # positions whose cell repeats
    if same.size == 0:
        return
    start = np.arange(order.size)   # first position of each run of equal cells
    first = np.ones(order.size, bool)
    first[same] = False
    start = np.maximum.accumulate(np.where(first, start, 0))
    a, b = order[start[same]], order[same]
    i, j = np.minimum(a, b), np.maximum(a, b)
    d = centers[j] - centers[i]
    near = np.sqrt(np.einsum("ij,ij->i", d, d)) <= COINCIDENT * np.maximum(radii[i], radii[j])
    if near.any():
        i, j = i[near], j[near]
        key = np.lexsort((j, i))
        raise coincident_error(i[key], j[key])


def find_pairs(centers, radii):
    """Bonded pairs (i, j), i < j, as two (M,) int64 arrays sorted by (i, j).

    A KD-tree proposes pairs closer than twice the largest radius; the exact
    test L < R_i + R_j keeps the bonds. Coincident centres are refused first
    (:func:`check_coincident`): a pile of them would make the candidate list quadratic.
    Where the C bond finder builds (amfe.model.pairkernel), it gives the same pairs, 5x faster
    on a `small` bed.
    """
    found = pairkernel.bonds(centers, radii, 2.0 * COINCIDENT)
    if found is not None:   # else coincident centres, too sparse, or no C kernel: the KD-tree
        return found[0], found[1]
    from scipy.spatial import cKDTree  # noqa: PLC0415 (0.07 s of a start-up that may not need it)

    check_coincident(centers, radii)
    tree = cKDTree(centers)
    pairs = tree.query_pairs(r=2.0 * float(radii.max()), output_type="ndarray")
    if pairs.size == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    del pairs
    lo, hi = bonded_among(centers, radii, np.minimum(i, j), np.maximum(i, j))
    key = lo * centers.shape[0] + hi  # one sort of (i, j) in place of a lexsort
    key.sort()
    lo = key // centers.shape[0]
    return lo, key - lo * centers.shape[0]


def bonded_among(centers, radii, i, j):
    """The pairs (i, j) (two (M,) int arrays) that are bonded, L < R_i + R_j, in their order.

    The test of :func:`find_pairs`, so bit for bit the same decisions.
    """
    d = centers[j] - centers[i]
    keep = np.einsum("ij,ij->i", d, d) < (radii[i] + radii[j]) ** 2
    return i[keep], j[keep]


@dataclass
class Bonds:
    """Geometry of M bonds. Lengths in the caller's unit; arrays (M,) unless noted.

    i, j: particle indices (i < j); normal (M,3): unit vector from i to j;
    length: L; d_i, d_j: distances of the contact plane from centres i and j
    (d_i + d_j = L); a: contact radius; r_eff: R_i R_j / (R_i + R_j);
    a_star: a / r_eff.
    """

    i: np.ndarray
    j: np.ndarray
    normal: np.ndarray
    length: np.ndarray
    d_i: np.ndarray
    d_j: np.ndarray
    a: np.ndarray
    r_eff: np.ndarray
    a_star: np.ndarray

    def __len__(self):
        return self.i.size

    def subset(self, mask):
        """The bonds selected by a boolean or index array."""
        return Bonds(**{k: v[mask] for k, v in self.__dict__.items()})


def neck(L, Ri, Rj):
    """(d_i, a, r_eff), each (M,), of bonds of centre distance L (M,) between radii Ri, Rj (M,):
    the contact plane's distance from centre i, the contact radius and R_i R_j / (R_i + R_j),
    in the caller's length unit. The contact radius takes the symmetric (Heron) form, which
    stays accurate for shallow overlaps where R_i^2 - d_i^2 cancels. No checks: see
    :func:`contact_geometry`."""
    d_i = (L**2 + Ri**2 - Rj**2) / (2.0 * L)
    heron = (Ri + Rj - L) * (L + Ri - Rj) * (L - Ri + Rj) * (Ri + Rj + L)
    a = np.sqrt(np.maximum(heron, 0.0)) / (2.0 * L)
    return d_i, a, Ri * Rj / (Ri + Rj)


def contact_geometry(centers, radii, i, j, offset=None):
    """Contact geometry of the bonds (i, j); raises AmfeError on degenerate pairs.

    ``offset`` (M,3), optional: added to x_j (a periodic bond joins i to an
    image of j, docs/model.md, section 9).

    Degenerate: coincident centres (L = 0) and a contact plane outside the
    segment between the centres (d_i <= 0 or d_j <= 0: a small sphere deep
    inside a large one). The contact radius: :func:`neck`.
    """
    Ri, Rj = radii[i], radii[j]
    branch = centers[j] - centers[i] if offset is None else centers[j] + offset - centers[i]
    L = np.sqrt(np.einsum("ij,ij->i", branch, branch))
    tiny = L <= COINCIDENT * np.maximum(Ri, Rj)
    if tiny.any():
        raise coincident_error(i[tiny], j[tiny])
    d_i, a, r_eff = neck(L, Ri, Rj)
    d_j = L - d_i
    inside = (d_i <= 0) | (d_j <= 0)
    if inside.any():
        raise AmfeError(f"{int(inside.sum())} bonds have their contact plane outside the segment "
                        "between the centres (a small sphere deep inside a large one): "
                        + _list_items(f"({a}, {b})" for a, b in zip(i[inside], j[inside]))
                        + ". Such overlaps are not sintered necks; fix the radii or positions.")
    return Bonds(i=i, j=j, normal=branch / L[:, None], length=L, d_i=d_i, d_j=d_j,
                 a=a, r_eff=r_eff, a_star=a / r_eff)


def find_bonds(centers, radii):
    """The :class:`Bonds` of checked particles (a :class:`~amfe.model.bed.Bed`'s arrays:
    :func:`validate_particles` ran when it was made)."""
    centers, radii = np.asarray(centers, float), np.asarray(radii, float)
    i, j = find_pairs(centers, radii)
    return contact_geometry(centers, radii, i, j)


A_STAR_CAP_MIN = 1e-3
"""The smallest a* cap: necks of a* = 1e-3 are the thinnest measured to solve
accurately (docs/hard_cases.md, near-mechanisms); a cap of 1e-300 underflows
the bending springs (~a*^4) to zero and leaves a singular frame."""


def check_a_star_cap(a_star_cap, material):
    """``a_star_cap`` as a float in [A_STAR_CAP_MIN, critical a* - A_STAR_MARGIN), else an error."""
    crit = critical_a_star(material.nu, material.psi)
    limit = crit - A_STAR_MARGIN
    try:
        cap = float(a_star_cap)
    except (TypeError, ValueError):
        cap = float("nan")
    if isinstance(a_star_cap, (bool, str)) or not (A_STAR_CAP_MIN <= cap < limit):
        raise AmfeError(f"the a* cap must lie in [{A_STAR_CAP_MIN:g}, {limit:.10f}) "
                        f"({A_STAR_MARGIN:g} below the critical a* {crit:.10f} for "
                        f"nu={material.nu}, psi={material.psi}; below {A_STAR_CAP_MIN:g} the "
                        f"bending springs vanish), got {a_star_cap!r}")
    return cap


CAP_FIX = ("Reduce the particle overlaps, or cap a* explicitly (--cap-a-star A with A < the "
           "critical value; the count of capped bonds is reported).")
"""The fix a bond past the critical a* names where a cap can be given (homogenize)."""


def bond_springs(bonds: Bonds, material: Material, a_star_cap=None, labels=None, fix=CAP_FIX):
    """Springs of every bond: (k_n, k_t, kappa_n, kappa_t, n_capped).

    Units follow the inputs: with lengths in m and E in Pa, k in N/m and kappa
    in N m. A bond at or past the critical a* (where the k_n denominator of
    eq. 1 vanishes, 0.9934 for the paper's nu and psi) has no physical spring:
    by default that is an error naming the bonds. With ``a_star_cap`` (< the
    critical value) such bonds, and any above the cap, are evaluated at
    a* = a_star_cap instead, and their number is returned as n_capped; bonds
    with a* >= 1 (overlaps too deep for a neck: nearly coincident spheres)
    stay errors. ``labels`` (N,) names particles in messages (default: their
    index in the arrays the bonds refer to). ``fix``: the advice ending that error
    (default :data:`CAP_FIX`, for callers that take a cap).
    """
    crit = critical_a_star(material.nu, material.psi)
    limit = crit - A_STAR_MARGIN  # closer than this no solve keeps accuracy
    a_star = bonds.a_star
    name = (lambda k: k) if labels is None else (lambda k: labels[k])  # noqa: E731
    if a_star_cap is None:
        bad = np.flatnonzero(a_star >= limit)
        if bad.size:
            worst = bad[np.argsort(-a_star[bad])]
            raise AmfeError(
                f"{bad.size} bonds reach a* >= {crit:.6f}, where the k_n and kappa_t "
                f"denominators of paper eqs. 1 and 4 vanish (nu={material.nu}, psi={material.psi}; "
                f"refused from {A_STAR_MARGIN:g} below it); their stiffness would be infinite, "
                "negative or beyond any solver's accuracy. Bonds (i, j, a*): "
                + _list_items(f"({name(bonds.i[k])}, {name(bonds.j[k])}, {a_star[k]:.6f})"
                              for k in worst)
                + ". " + fix
            )
        capped = np.zeros(a_star.shape, bool)
        s = a_star
    else:
        a_star_cap = check_a_star_cap(a_star_cap, material)
        deep = np.flatnonzero(a_star >= 1.0)
        if deep.size:
            raise AmfeError(
                f"{deep.size} bonds have a* >= 1, overlaps too deep for a sintered neck (nearly "
                "coincident spheres; eqs. 1-4 are imaginary there), which no a* cap covers. "
                "Bonds (i, j, a*): "
                + _list_items(f"({name(bonds.i[k])}, {name(bonds.j[k])}, {a_star[k]:.6f})"
                              for k in deep[np.argsort(-a_star[deep])])
                + ". Remove the duplicated particles.")
        capped = a_star > a_star_cap
        s = np.minimum(a_star, a_star_cap)
    k_n, k_t, kappa_n, kappa_t = spring_constants(s * bonds.r_eff, bonds.r_eff, material)
    return k_n, k_t, kappa_n, kappa_t, int(capped.sum())

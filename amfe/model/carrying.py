"""What carries load under each boundary condition, and the bed's box (docs/model.md, section 5).

Pure numpy on the bond graph of the whole input bed. A connected component of
full 6-DOF bonds has exactly six rigid-body modes; it carries load in the
linear problem when the condition's constraints and loads remove all six and
reach it, and it is removed otherwise (it would take no stress, or make the
problem singular). The rules, derived in section 5:

- KUBC (and mixed): a component is held when its prescribed particles (KUBC's
  boundary set on the box of the held centres) do not lie on one line: their
  translations t + omega x (x_p - x_c) = 0 then force t = omega = 0. Tested as
  "some prescribed centre lies at least ``HELD_OFF_LINE`` mean radii from the
  least-squares line through them" (fewer than three never are).
- SUBC: a component takes its share of the face loads Sigma n_F A_F; they
  balance on it only if it reaches both faces of every axis, so a component
  is kept when it holds boundary particles on all six faces; each kept one
  gets its own self-equilibrated weights and its own pin. The search starts
  from KUBC's pieces (every piece reaching six faces is held by KUBC).
- periodic: a component carries macro-strain when it winds round the torus;
  winding in two or three independent directions leaves only the three
  translations free (a rotation omega is periodic only if omega x w = 0 for
  every winding w), one pinned particle each. A component winding in one
  direction only keeps the rotation about it as a mechanism: an error.

Both finite selections are fixed points: the box (and so the boundary set)
is that of the kept centres, and the selection is repeated until it stops
changing (the kept set only shrinks, so this ends).
"""
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from amfe.errors import AmfeError
from amfe.model.averages import hull_of
from amfe.model.bonds import find_pairs, validate_particles
from amfe.model.torus import spanning_images, winding_rank

#: A component is held by KUBC when a prescribed centre lies this many mean radii off
#: the line through the others (a smaller offset is a near mechanism: docs/hard_cases.md).
HELD_OFF_LINE = 0.5

#: Largest number of removed components listed one by one in the result.
LISTED = 20


def component_labels(n, i, j):
    """Labels (n,) int: the connected component of each particle in the bond graph (i, j)."""
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def boundary_faces(x, radii):
    """(on_lo, on_hi) (n,3) bool: centre within max(radii) of each face of the centres' box."""
    rmax = float(np.max(radii))
    lo, hi = x.min(axis=0), x.max(axis=0)
    return (x - lo) <= rmax, (hi - x) <= rmax


def off_line(points):
    """Largest distance (float) of ``points`` (k,3) from their least-squares line (0 if k < 3)."""
    if points.shape[0] < 3:
        return 0.0
    d = points - points.mean(axis=0)
    axis = np.linalg.svd(d, full_matrices=False)[2][0]
    return float(np.max(np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)))


def _fixed_point(x, r, labels, keep_components, start=None):
    """Components kept by ``keep_components(mask, on_lo, on_hi) -> kept ids`` at its fixed
    point, starting from the ids ``start`` (default all)."""
    kept = np.unique(labels) if start is None else start
    while True:
        mask = np.isin(labels, kept)
        on_lo = np.zeros(x.shape, bool)
        on_hi = np.zeros(x.shape, bool)
        on_lo[mask], on_hi[mask] = boundary_faces(x[mask], r[mask])
        new = keep_components(mask, on_lo, on_hi)
        if new.size == 0 or np.array_equal(new, kept):
            return new
        kept = new


def kubc_held(x, r, labels):
    """Component ids (sorted) that KUBC's prescribed translations hold (module docstring)."""
    tol = HELD_OFF_LINE * float(np.mean(r))
    strays = stray_pieces(x, r, labels)

    def keep(mask, on_lo, on_hi):
        idx = np.flatnonzero(mask & (on_lo | on_hi).any(axis=1))
        idx = idx[np.argsort(labels[idx], kind="stable")]
        ids, start = np.unique(labels[idx], return_index=True)
        groups = np.split(idx, start[1:])
        return np.array([c for c, g in zip(ids, groups) if off_line(x[g]) >= tol], np.int64)
    start = np.setdiff1d(np.unique(labels), strays) if strays.size else None
    kept = _fixed_point(x, r, labels, keep, start)
    if kept.size == 0:
        raise AmfeError("no bonded piece of the bed is held by the boundary conditions: none "
                        "has three prescribed boundary particles off one line (a chain, whose "
                        "centres span no volume, or pieces too small), so nothing carries load")
    return kept


def subc_spanning(x, r, labels):
    """Component ids (sorted) that reach all six faces of the box of the kept centres.

    AmfeError when none does: no self-equilibrated boundary loads cross the box
    (two blocks side by side), the message names the faces the largest piece misses.
    """
    def keep(mask, on_lo, on_hi):
        n = labels.max() + 1
        faces = [np.bincount(labels[mask], weights=on[mask, a], minlength=n) > 0
                 for on in (on_lo, on_hi) for a in range(3)]
        return np.flatnonzero(np.all(faces, axis=0) & (np.bincount(labels[mask], minlength=n) > 0))
    # from KUBC's pieces: a piece SUBC can load is held by KUBC, and KUBC's fixed point has
    # already dropped the small pieces that would widen the box
    held = kubc_held(x, r, labels)
    kept = _fixed_point(x, r, labels, keep, start=held)
    if kept.size == 0:                     # name what the largest held piece misses
        mask = np.isin(labels, held)
        big = labels == np.argmax(np.bincount(labels[mask], minlength=labels.max() + 1))
        on_lo = np.zeros(x.shape, bool)
        on_hi = np.zeros(x.shape, bool)
        on_lo[mask], on_hi[mask] = boundary_faces(x[mask], r[mask])
        missing = [s + "xyz"[a] for a in range(3) for s, on in (("-", on_lo), ("+", on_hi))
                   if not on[big, a].any()]
        raise AmfeError(
            f"SUBC: no load path across the box: no bonded piece reaches all six faces (the "
            f"largest, {int(big.sum())} particles, misses the {', '.join(missing)} face(s)), "
            "so the face loads of a macro-stress balance on none of them; use --bc kubc")
    return kept


def periodic_winding(n, i, j, shift, labels):
    """Component ids (sorted) that wind round the torus in 2 or 3 directions.

    i, j (M,) bonds, shift (M,3) their image shifts, labels (n,) components.
    AmfeError for a component winding in one direction only, or when the kept
    components' windings span fewer than three directions (no macro-stress
    along the others).
    """
    kept, windings = [], []
    crossing = np.any(shift != 0, axis=1)
    for c in np.unique(labels[i[crossing]]):
        members = np.flatnonzero(labels == c)
        local = np.full(n, -1, np.int64)
        local[members] = np.arange(members.size)
        b = labels[i] == c
        w = spanning_images(members.size, local[i[b]], local[j[b]], shift[b])[1]
        rank = winding_rank(w)
        if rank == 1:
            raise AmfeError(
                f"a bonded piece of {members.size} particles winds round the torus in one "
                "direction only: it carries load along it but turns freely about it "
                "(a mechanism amfe does not model); use a denser bed")
        if rank >= 2:
            kept.append(c)
            windings.append(w)
    rank = winding_rank(np.concatenate(windings)) if windings else 0
    if rank < 3:
        raise AmfeError(f"the load-carrying cluster of the periodic bed wraps round the torus in "
                        f"only {rank} of 3 independent directions: it does not percolate, so it "
                        "carries no macro-stress along the others; use a denser bed")
    return np.array(kept, np.int64)


#: A piece is small when it holds under this share of the particles, or cannot span a volume.
STRAY_SHARE = 0.05

#: A small piece is a stray when a centre of it lies this many largest diameters or more
#: outside the spheres' box of the other pieces (a gap two particles would fit in): no
#: generated bed's piece lies so far out, while a small piece held at the bed's face just
#: outside its box (tests/test_carrying.py) is still no stray.
STRAY_GAP = 2.0


def stray_pieces(x, r, labels):
    """Component ids (sorted) of the stray pieces: small pieces lying apart from the bed.

    A piece is small when it holds fewer than :data:`STRAY_SHARE` of the particles,
    fewer than 4, or centres spanning under one mean radius along an axis (no volume);
    a small piece is a stray when a centre of it lies :data:`STRAY_GAP` largest
    diameters or more outside the spheres' box of the pieces that are not small.
    Strays must not define the box (KUBC would grip them and not the bed: issue 45,
    item 6), so :func:`kubc_held` leaves them out and they are removed. Empty when
    every piece is small (then the box rule is the plain one).
    """
    n = labels.max() + 1
    count = np.bincount(labels, minlength=n)
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, labels, x)
    np.maximum.at(hi, labels, x)
    thin = np.min(hi - lo, axis=1) < float(np.mean(r))
    small = (count > 0) & ((count < STRAY_SHARE * labels.size) | (count < 4) | thin)
    big = ~small[labels]
    if not big.any():
        return np.zeros(0, np.int64)
    box_lo = (x[big] - r[big, None]).min(axis=0)
    box_hi = (x[big] + r[big, None]).max(axis=0)
    gap = STRAY_GAP * 2.0 * float(np.max(r))
    out = np.any((x < box_lo - gap) | (x > box_hi + gap), axis=1)
    return np.flatnonzero(small & (np.bincount(labels, weights=out, minlength=n) > 0))


#: Where V's box came from (:func:`box_rule`), in the words the result uses.
BOX_SOURCES = ("recorded size", "periodic box", "spheres' box", "given box")


class GivenBox(tuple):
    """(Lx, Ly, Lz): a box the user gives (issue 48's --box); as ``size`` of
    :func:`box_rule` (or of :func:`amfe.model.frame.build_frame`) it is ``given``."""


def box_rule(centers, radii, size=None, kept=None, given=None):
    """(L (3,), note, source): the bed's box lengths, whose product is V, in the arguments' units.

    The one box rule (docs/model.md, section 5). ``given`` (3,): a box the user
    states (issue 48's --box); it must hold the load-carrying centres (``kept``,
    indices; default all), else AmfeError; source "given box". ``size`` (3,): the
    generated bed's recorded box (attrs ``size``, the box its image covers), used
    when it holds the extent of the load-carrying centres; source "recorded size".
    Otherwise, or without either: the smallest axis-aligned box holding every
    load-carrying sphere, max(x + R) - min(x - R) per axis; source "spheres' box",
    and note says why the recorded size was not used (a bed edited after
    generation), else it is None. A periodic bed's box is its periods (source
    "periodic box", set by the frame). Either way a floating or stray piece
    (:func:`stray_pieces`), kept out, changes no volume.
    """
    if isinstance(size, GivenBox):
        size, given = None, size
    x = np.asarray(centers, dtype=float)
    r = np.asarray(radii, dtype=float)
    x, r = (x, r) if kept is None else (x[kept], r[kept])
    spheres = (x + r[:, None]).max(axis=0) - (x - r[:, None]).min(axis=0)
    extent = np.ptp(x, axis=0)
    if given is not None:
        L = _three_lengths(given, "the given box")
        if np.any(extent > L * (1 + 1e-9)):
            axis = "xyz"[int(np.argmax(extent / L))]
            raise AmfeError(f"the given box {' x '.join(f'{v:.4g}' for v in L)} m does not "
                            f"hold the load-carrying centres: they span "
                            f"{float(np.max(extent / L)):.4g} times its length along {axis}; "
                            f"give at least {' x '.join(f'{v:.4g}' for v in extent)} m")
        return L, None, "given box"
    if size is None:
        return spheres, None, "spheres' box"
    L = _three_lengths(size, "the bed's size")
    if np.any(extent > L * (1 + 1e-9)):
        over = 100 * float(np.max(extent / L - 1))
        return spheres, (f"the bed's recorded size does not hold its load-carrying centres "
                         f"(their extent exceeds it by up to {over:.3g} %; edited after "
                         "generation?): V is their spheres' bounding box instead "
                         "(docs/model.md, section 5)"), "spheres' box"
    return L, None, "recorded size"


def _three_lengths(value, what):
    L = np.asarray(value, dtype=float).reshape(-1)
    if L.shape != (3,) or not np.all(np.isfinite(L) & (L > 0)):
        raise AmfeError(f"{what} must be three positive lengths, got {value!r}")
    return L


def bed_box(centers, radii, size=None, kept=None, given=None):
    """(L (3,), note): :func:`box_rule` without the source."""
    return box_rule(centers, radii, size, kept, given)[:2]


def removed_report(x, r, labels, kept_ids, n_input):
    """The removed components: a dict for the result (docs/model.md, section 6).

    x (n,3), r (n,) any one length unit; labels (n,) components; kept_ids the
    kept components. share: of the particles' solid volume sum 4/3 pi R^3
    (overlaps counted twice); touches_boundary: a particle of it lies in the
    boundary layer of the box of all input centres.
    """
    gone = ~np.isin(labels, kept_ids)
    solid = r ** 3
    on_lo, on_hi = boundary_faces(x, r)
    touch = (on_lo | on_hi).any(axis=1)
    ids, sizes = np.unique(labels[gone], return_counts=True)
    order = np.argsort(-sizes, kind="stable")
    share = np.bincount(labels, weights=solid)[ids] / solid.sum()
    touching = np.bincount(labels, weights=touch.astype(float))[ids] > 0
    listed = [{"particles": int(sizes[k]), "volume_share": float(share[k]),
               "touches_boundary": bool(touching[k])} for k in order[:LISTED]]
    return {"components": int(ids.size), "particles": int(gone.sum()),
            "particle_share": float(gone.sum() / n_input),
            "volume_share": float(share.sum()), "touching_boundary": int(touching.sum()),
            "largest": listed}


# The carrying rules of the boundary-condition table (amfe.model.conditions), one signature:
# (x (n,3), r (n,), bonds i, j (M,), shift (M,3) or None, box (3,) or None, labels (n,)) ->
# the sorted ids of the load-carrying components.

def kubc_carrying(x, r, i, j, shift, box, labels):
    """KUBC: the components its prescribed boundary translations hold."""
    return kubc_held(x, r, labels)


def mixed_carrying(x, r, i, j, shift, box, labels):
    """Mixed conditions: KUBC's rule, and one held piece at most (the paper's grips hold one
    frame; each piece would keep its own free rigid motions)."""
    ids = kubc_held(x, r, labels)
    if ids.size > 1:
        raise AmfeError(f"mixed conditions: the bed has {ids.size} separate load-carrying pieces; "
                        "the grips of the paper's experiments hold one frame (each piece would "
                        "keep its own free rigid motions): use --bc kubc")
    return ids


def subc_carrying(x, r, i, j, shift, box, labels):
    """SUBC: the components that reach all six faces."""
    return subc_spanning(x, r, labels)


def periodic_carrying(x, r, i, j, shift, box, labels):
    """Periodic: the components that wind round the torus."""
    return periodic_winding(x.shape[0], i, j, shift, labels)


#: Share of the particles above which removing them is a warning.
WARN_SHARE = 0.01


def frame_warnings(frame, bc):
    """The frame's warnings for the result: the box rule's note, the removed pieces."""
    return ([frame.box_note] if frame.box_note else []) + removed_warning(frame.removed, bc)


def removed_warning(removed, bc):
    """[message] when more than :data:`WARN_SHARE` of the particles were removed, else []."""
    if removed["particle_share"] <= WARN_SHARE:
        return []
    big = removed["largest"][0]
    return [f"{removed['particles']} particles ({100 * removed['particle_share']:.1f} %, "
            f"{100 * removed['volume_share']:.1f} % of the solid volume) in "
            f"{removed['components']} piece(s) carry no load under {bc} and were removed "
            f"({removed['touching_boundary']} of them touch the boundary; the largest has "
            f"{big['particles']} particles); the constants are those of the rest, in the "
            "bed's whole box (docs/model.md, section 5)"]


def rule1_factor(centers, radii, size=None):
    """V_hull / V_box (float): label rule 1's volume over rule 2's, for a KUBC label.

    Rule 1 (before issue 30) kept the largest bonded component and used the hull
    of its centres; rule 2 uses the bed's box (:func:`bed_box` with ``size``,
    the recorded size). Where rule 2 keeps the same piece, every rule-1 modulus
    times this factor is the rule-2 one exactly (the Poisson ratios do not
    move): the conversion of a surrogate trained on rule-1 labels.
    centers (N,3), radii (N,) [m]; size (3,) [m] or None.
    """
    x, r = validate_particles(centers, radii)
    length = float(r.mean())                      # as build_frame finds the bonds
    i, j = find_pairs(x / length, r / length)
    labels = component_labels(x.shape[0], i, j)
    largest = np.flatnonzero(labels == np.argmax(np.bincount(labels)))
    L = bed_box(x, r, size, largest)[0]
    return hull_of(x[largest]).volume / float(np.prod(L))

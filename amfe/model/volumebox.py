"""V's box placed in space, the result's record of it, and the metre-plausibility check.

:func:`amfe.model.carrying.box_rule` gives V's lengths and where they came
from (docs/model.md, section 5). The voxel model meshes that box and the
density is measured in it, so it also needs a place: :func:`placed_box`. The
result's ``volume_box`` record (:func:`volume_box_record`) says V, the box and
its source, so that two runs whose V differ (a file with or without a
recorded size, issue 48) say why.
"""
import numpy as np

from amfe.model.carrying import box_rule

#: Lengths a bed in metres lies between; a bed outside them was likely written in another
#: unit (micrometres: radii of 20, or millimetres: radii of 0.02).
PLAUSIBLE_METRES = (1e-7, 1.0)


def placed_box(centers, radii, size=None, kept=None, given=None):
    """(lo (3,), L (3,), note, source): V's box, placed in the coordinates of ``centers``.

    L, note and source are :func:`~amfe.model.carrying.box_rule`'s. A recorded
    size is [0, L] where the load-carrying centres (``kept``, indices; default
    all) lie in it (a generated bed: the box its images cover), else centred on
    their extent; a given box (``given``, or ``size`` a GivenBox) is centred on
    their extent; the spheres' box is their bounding box. centers (N, 3),
    radii (N,), size and given (3,): any one length unit.
    """
    L, note, source = box_rule(centers, radii, size, kept, given)
    x = np.asarray(centers, dtype=float)
    r = np.asarray(radii, dtype=float)
    x, r = (x, r) if kept is None else (x[kept], r[kept])
    if source == "spheres' box":
        lo = (x - r[:, None]).min(axis=0)
    elif source == "recorded size" and np.all((x >= -1e-9 * L) & (x <= L * (1 + 1e-9))):
        lo = np.zeros(3)
    else:
        lo = 0.5 * (x.min(axis=0) + x.max(axis=0) - L)
    return lo, L, note, source


def volume_box_record(lo, L, source, note=None) -> dict:
    """The result's ``volume_box``: V [m^3], the box's lower corner ``lo`` (3,) [m] and lengths
    ``size`` (3,) [m] in the input's coordinates, where V came from, and why a recorded size
    was not used (or None)."""
    L = np.asarray(L, dtype=float)
    return {"V": float(np.prod(L)), "lo": [float(v) for v in lo],
            "size": [float(v) for v in L], "source": source, "note": note}


def unit_warnings(radii, size) -> list:
    """[message] when the radii or V's box lengths (both [m]) lie outside
    :data:`PLAUSIBLE_METRES`: a bed written in micrometres or millimetres, not metres."""
    lo, hi = PLAUSIBLE_METRES
    out = []
    for what, values in (("radii", np.asarray(radii, float)), ("box", np.asarray(size, float))):
        small, large = float(values.min()), float(values.max())
        if small < lo or large > hi:
            out.append(f"the bed's {what} span {small:.3g}-{large:.3g} m, outside the "
                       f"{lo:g}-{hi:g} m of a powder bed in metres: was it written in micrometres "
                       "or millimetres? amfe reads every length in metres (the moduli do not "
                       "depend on the unit; V and the density's box do)")
    return out

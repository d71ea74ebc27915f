"""Extrapolation in the mesh size to h -> 0, with an error estimate, pure numpy.

docs/model.md, section 10 ("Convergence in H"). A quantity computed at mesh
sizes h (any units, any ratios) is modelled as f(h) = f0 + a h^p. With three
sizes the order p follows from the two differences (the generalised
Richardson extrapolation of Celik et al., "Procedure for estimation and
reporting of uncertainty due to discretization in CFD applications",
J. Fluids Eng. 130, 078001, 2008), and the error estimate is Roache's grid
convergence index, GCI = Fs |f1 - f2| / (r^p - 1), with r = h2 / h1 the
ratio of the two finest sizes:

- the observed order is used, with Fs = 1.25, when the three values converge
  monotonically and the order lies in [:data:`P_MIN`, :data:`P_MAX`];
- otherwise (oscillating values, or an order outside that range: the ladder
  is not in its asymptotic range) the order is the staircase's, p = 1
  (:data:`P_FALLBACK`), from the two finest sizes, with Roache's safety
  factor Fs = 3 for an order not verified.

With four sizes or more, every other triple of consecutive sizes is
extrapolated by the same rule too, and the error is at least the largest
distance of their values from the finest triple's (``spread``): a voxel
ladder carries the grid's alignment noise, which can fake a clean order on
one triple.
"""
import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import brentq

from amfe.errors import AmfeError

P_MIN, P_MAX = 0.5, 3.0
"""Observed orders accepted (a voxelised surface converges at order 1, a smooth
solution of trilinear elements in energy at order 2)."""
P_FALLBACK = 1.0
"""Order assumed when the observed one is not accepted: the staircase's."""
FS_VERIFIED, FS_ASSUMED = 1.25, 3.0
"""Roache's safety factors for an observed order and an assumed one."""


@dataclass(frozen=True)
class Extrapolation:
    """f0 ~ value +- error at h -> 0.

    value: the extrapolated f0; error: the GCI (absolute, f's units);
    order: the p used; observed_order: the p of the three finest values (nan
    when none is positive or they oscillate); factor: Fs; monotone: the three
    finest values converge without oscillating; finest: f at the smallest h;
    note: why the observed order was not used ("" when it was).
    """

    value: float
    error: float
    order: float
    observed_order: float
    factor: float
    monotone: bool
    finest: float
    note: str
    spread: float = 0.0

    def as_dict(self):
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def observed_order(h, f):
    """p with (f3 - f2) / (f2 - f1) = (h3^p - h2^p) / (h2^p - h1^p), h1 < h2 < h3.

    h (3,), f (3,) in any order of h. nan when the differences change sign, one
    is zero, or no positive p fits (the ratio is below its p -> 0 limit,
    ln(h3/h2) / ln(h2/h1): the values converge more slowly than any power).
    """
    h, f = _sorted(h, f)
    h = h / h[0]                        # ratios only: h^p of sizes in metres underflows
    e21, e32 = f[1] - f[0], f[2] - f[1]
    if e21 == 0 or e32 == 0 or (e32 / e21) <= 0:
        return float("nan")
    target = math.log(e32 / e21)

    def g(p):  # log of the power law's ratio, increasing in p
        return math.log(h[2] ** p - h[1] ** p) - math.log(h[1] ** p - h[0] ** p) - target

    lo, hi = 1e-6, 50.0
    if g(lo) > 0 or g(hi) < 0:
        return float("nan")
    return brentq(g, lo, hi, xtol=1e-14, rtol=1e-14)


def extrapolate(h, f):
    """The :class:`Extrapolation` of values f (k,) at mesh sizes h (k,), k >= 2.

    Three or more sizes: the three finest decide (observed order and GCI, see
    the module). Two: order 1 and Fs = 3. Raises AmfeError for fewer than two
    sizes, repeated sizes, or non-finite values.
    """
    h, f = np.asarray(h, float).ravel(), np.asarray(f, float).ravel()
    if h.size != f.size:
        raise AmfeError(f"extrapolation needs one value per mesh size, got {f.size} for {h.size}")
    if h.size < 2:
        raise AmfeError(f"extrapolation needs at least two mesh sizes, got {h.size}")
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(f)) and np.all(h > 0)):
        raise AmfeError("extrapolation needs positive mesh sizes and finite values")
    h, f = _sorted(h, f)
    if np.any(np.diff(h) <= 0):
        raise AmfeError(f"extrapolation needs distinct mesh sizes, got {h.tolist()}")
    r = h[1] / h[0]
    p_obs, monotone, note = float("nan"), False, "two sizes only"
    if h.size >= 3:
        e21, e32 = f[1] - f[0], f[2] - f[1]
        monotone = bool(e21 * e32 > 0)
        p_obs = observed_order(h[:3], f[:3])
        if not monotone:
            note = "the three finest values oscillate"
        elif not (P_MIN <= p_obs <= P_MAX):
            note = (f"observed order {p_obs:.2f} outside [{P_MIN}, {P_MAX}]"
                    if math.isfinite(p_obs) else "no positive order fits")
        else:
            note = ""
    p, fs = (p_obs, FS_VERIFIED) if note == "" else (P_FALLBACK, FS_ASSUMED)
    step = (f[0] - f[1]) / (r ** p - 1.0)
    value = float(f[0] + step)
    spread = max((abs(extrapolate(h[i:i + 3], f[i:i + 3]).value - value)
                  for i in range(1, h.size - 2)), default=0.0)
    return Extrapolation(value=value, error=float(max(fs * abs(step), spread)), order=float(p),
                         observed_order=float(p_obs), factor=fs, monotone=monotone,
                         finest=float(f[0]), note=note, spread=float(spread))


def fit_order(h, f, p):
    """(f0, a): least squares of f = f0 + a h^p at a given order p over all sizes (k >= 2)."""
    h, f = np.asarray(h, float).ravel(), np.asarray(f, float).ravel()
    A = np.stack([np.ones_like(h), h ** p], axis=1)
    (f0, a), *_ = np.linalg.lstsq(A, f, rcond=None)
    return float(f0), float(a)


def _sorted(h, f):
    """h ascending (finest first) and f in the same order."""
    order = np.argsort(h)
    return np.asarray(h, float)[order], np.asarray(f, float)[order]

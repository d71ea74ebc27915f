"""The size rule: a bed of any in-plane size from the models of the shipped sizes (issue 46).

Under KUBC a bed's apparent moduli fall towards the bulk ones as its boundary
layer's share of the bed falls, about as 1/L (the share of the particles
within a fixed depth of the faces). The shipped models (0.6, 1.2 and 3 mm)
are fully convolutional with global pooling (amfe.training.multiscale), so
each reads an image of any H x W; the rule predicts a bed of size L with the
two shipped models nearest in 1/L, each on the bed's own image, and
interpolates their outputs linearly in 1/L (extrapolates past 3 mm, up to
:data:`MAX_SIZE`). 1/L is the mean of 1/Lx and 1/Ly (the faces' share is
proportional to 1/Lx + 1/Ly), L in mm.

Measured on held-out beds (docs/surrogate.md, "Any size"): 0.9 x 0.9 mm, 300
beds: mean relative errors 2.5, 2.7, 1.7, 2.4, 2.4, 3.2 % (Ex ... nu_xy),
against 3.1-4.8 % for the 1.2 mm model alone and 2.7-7.3 % for the 0.6 mm one.
"""
from amfe.errors import AmfeError

#: The shipped sizes [mm] the rule interpolates between, smallest first.
SIZES = (0.6, 1.2, 3.0)
#: The covered range of in-plane sides [mm] (the largest extrapolates from 1.2 and 3 mm).
MIN_SIZE, MAX_SIZE = 0.6, 4.0
#: Sides within this of the range's ends [mm] count as in it (0.6 mm is 20 cells of 0.03).
SIZE_TOL = 1e-6


def inverse_size(lx_mm, ly_mm):
    """1/L [1/mm] of a bed of sides lx_mm, ly_mm: the mean of 1/Lx and 1/Ly."""
    return 0.5 * (1.0 / float(lx_mm) + 1.0 / float(ly_mm))


def check_size(lx_mm, ly_mm):
    """AmfeError, quoting the bed's sides and the range, for a side outside
    [MIN_SIZE, MAX_SIZE] mm."""
    for side in (lx_mm, ly_mm):
        if not MIN_SIZE - SIZE_TOL <= float(side) <= MAX_SIZE + SIZE_TOL:
            raise AmfeError(f"the bed is {float(lx_mm):g} x {float(ly_mm):g} mm; the surrogate "
                            f"covers sides from {MIN_SIZE:g} to {MAX_SIZE:g} mm (solve it: "
                            "amfe homogenize)")


def size_weights(lx_mm, ly_mm):
    """[(shipped size [mm], weight), ...]: the rule's models and weights for a bed (the
    weights sum to 1; one is negative past 3 mm, where the rule extrapolates)."""
    check_size(lx_mm, ly_mm)
    inv = inverse_size(lx_mm, ly_mm)
    for a, b in zip(SIZES, SIZES[1:]):
        if inv >= 1.0 / b - 1e-12:
            break
    t = (inv - 1.0 / a) / (1.0 / b - 1.0 / a)
    if abs(t) < 1e-9:
        return [(a, 1.0)]
    if abs(t - 1.0) < 1e-9:
        return [(b, 1.0)]
    return [(a, 1.0 - t), (b, t)]

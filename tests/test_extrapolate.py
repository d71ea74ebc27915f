"""Extrapolation in the mesh size (docs/model.md, section 10, "Convergence in H")."""
import math

import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.model.extrapolate import (
    FS_ASSUMED,
    FS_VERIFIED,
    P_FALLBACK,
    extrapolate,
    fit_order,
    observed_order,
)

# voxel sizes R/4, R/6, R/8, R/12 in units of R: ratios 1.5, 1.33, 1.5 (not constant)
H = 1.0 / np.array([4.0, 6.0, 8.0, 12.0])


@pytest.mark.parametrize("p", [0.7, 1.0, 1.5, 2.0, 2.8])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_pure_power_law_is_recovered_exactly(p, sign):
    f0, a = 170.0, sign * 40.0
    f = f0 + a * H ** p
    e = extrapolate(H, f)
    assert e.observed_order == pytest.approx(p, rel=1e-9)
    assert e.order == e.observed_order and e.factor == FS_VERIFIED and e.monotone
    assert e.value == pytest.approx(f0, rel=1e-12)
    # the GCI: Fs times the step from the finest value to the extrapolated one
    assert e.error == pytest.approx(FS_VERIFIED * abs(f[-1] - f0), rel=1e-9)
    assert e.finest == f[-1] and e.note == ""
    # order of the sizes given does not matter
    perm = [2, 0, 3, 1]
    assert extrapolate(H[perm], f[perm]).value == pytest.approx(e.value, rel=1e-14)


def test_sizes_in_metres_give_the_same_answer():
    f = 0.3 + 0.2 * H ** 0.8
    e, m = extrapolate(H, f), extrapolate(H * 1e-6, f)      # voxel sizes of a 1 um radius
    assert m.value == pytest.approx(e.value, rel=1e-12) and m.order == pytest.approx(0.8)
    f = np.array([0.3538, 0.3202, 0.3060])                   # measured at R/4, R/6, R/8
    assert math.isfinite(extrapolate(1e-6 / np.array([4, 6, 8]), f).value)


def test_the_three_finest_decide_and_a_coarser_triple_widens_the_error():
    f = 5.0 + 2.0 * H ** 1.5
    assert extrapolate(H, f).spread < 1e-12     # every triple of a power law agrees
    f[0] += 1.0                         # a coarse level off the power law (alignment noise)
    e = extrapolate(H, f)
    assert e.value == pytest.approx(5.0, rel=1e-12)
    coarse = extrapolate(H[:3], f[:3]).value
    assert e.spread == pytest.approx(abs(coarse - 5.0), abs=1e-12) and e.spread > 0.01
    assert e.error == pytest.approx(max(e.spread, FS_VERIFIED * abs(f[-1] - 5.0)), rel=1e-12)


def test_the_error_estimate_covers_a_second_order_term():
    # f0 + a h + b h^2: the power law is only the leading term; the GCI must cover f0
    for a, b in [(30.0, 50.0), (30.0, -40.0), (-20.0, 60.0), (10.0, 200.0)]:
        f = 100.0 + a * H + b * H ** 2
        e = extrapolate(H, f)
        assert abs(e.value - 100.0) <= e.error, (a, b, e)
        assert abs(e.value - 100.0) < abs(f[-1] - 100.0)   # better than the finest value


def test_oscillating_values_fall_back_to_order_one_with_safety_factor_three():
    h = np.array([0.25, 1 / 6, 0.125])
    f = np.array([2.0, 2.2, 2.1])       # up then down: no power law
    e = extrapolate(h, f)
    assert not e.monotone and math.isnan(e.observed_order)
    assert e.order == P_FALLBACK and e.factor == FS_ASSUMED
    r = (1 / 6) / 0.125
    step = (2.1 - 2.2) / (r - 1)
    assert e.value == pytest.approx(2.1 + step, rel=1e-12)
    assert e.error == pytest.approx(3 * abs(step), rel=1e-12)
    assert "oscillate" in e.note


def test_slower_than_any_power_falls_back():
    f = 10.0 + np.log(H)                # logarithmic: differences shrink slower than any h^p
    assert math.isnan(observed_order(H[1:], f[1:]))
    e = extrapolate(H, f)
    assert e.order == P_FALLBACK and e.factor == FS_ASSUMED and "no positive order" in e.note
    f = 10.0 + H ** 4.0                 # converges monotonically, but faster than P_MAX
    e = extrapolate(H, f)
    assert e.observed_order == pytest.approx(4.0, rel=1e-9) and e.order == P_FALLBACK


def test_two_sizes_extrapolate_at_order_one():
    h, f = np.array([0.2, 0.1]), 7.0 + 3.0 * np.array([0.2, 0.1])
    e = extrapolate(h, f)
    assert e.value == pytest.approx(7.0, rel=1e-13) and e.order == 1.0
    assert e.error == pytest.approx(3 * 0.3, rel=1e-12)
    assert e.as_dict()["observed_order"] is None   # nan leaves as JSON null


def test_fit_order_is_least_squares_at_a_given_order():
    f = 3.0 - 2.0 * H ** 2
    assert fit_order(H, f, 2.0) == pytest.approx((3.0, -2.0), rel=1e-12)
    f1 = 3.0 + H                        # at the wrong order the fit is not exact
    assert abs(fit_order(H, f1, 2.0)[0] - 3.0) > 1e-3


@pytest.mark.parametrize("h, f", [([0.1], [1.0]), ([0.1, 0.1], [1.0, 2.0]),
                                  ([0.1, -0.2], [1.0, 2.0]), ([0.1, 0.2], [1.0, np.nan]),
                                  ([0.1, 0.2, 0.3], [1.0, 2.0])])
def test_bad_input_is_a_clear_error(h, f):
    with pytest.raises(AmfeError, match="extrapolation"):
        extrapolate(h, f)

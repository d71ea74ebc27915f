"""Springs of paper eqs. 1-4 against values worked by hand, and the critical a*."""
import math

import numpy as np
import pytest

from amfe.model.material import Material
from amfe.model.springs import critical_a_star, normal_denominator, spring_constants


def test_springs_by_hand_at_half():
    # a* = 0.5, R = 2 um -> a = 1 um; E = 210 GPa, nu = 0.28, psi = 0.08.
    # bracket g = pi/6 (1 - nu^2)(1 + 2a*) - a* = pi/6 * 0.9216 * 2 - 0.5
    # numerator  = 1 + a* g
    # root       = sqrt(1 - 0.25) = sqrt(0.75)
    # denominator (eqs. 1, 4) = root - psi (a* + a*^2 g)
    # k_n     = E a / (1 - nu^2) * num / den
    # k_t     = 2 E a / ((2 - nu)(1 + nu)) * num / root
    # kappa_n = 8 E R^3 a*^3 / ((2 - nu)(1 + nu)) * num / root
    # kappa_t = 2 E R^3 a*^3 / (1 - nu^2) * num / den
    E, nu, psi, R, s = 210e9, 0.28, 0.08, 2e-6, 0.5
    a = s * R
    g = math.pi / 6 * 0.9216 * 2 - 0.5
    assert g == pytest.approx(0.4650973, abs=1e-7)
    num = 1 + 0.5 * g
    root = math.sqrt(0.75)
    den = root - 0.08 * (0.5 + 0.25 * g)
    expect = [
        E * a / 0.9216 * num / den,
        2 * E * a / (1.72 * 1.28) * num / root,
        8 * E * R**3 * 0.125 / (1.72 * 1.28) * num / root,
        2 * E * R**3 * 0.125 / 0.9216 * num / den,
    ]
    got = spring_constants(np.array([a]), np.array([R]), Material(E=E, nu=nu, psi=psi))
    for g_, e_ in zip(got, expect):
        assert g_[0] == pytest.approx(e_, rel=1e-14)


def test_critical_a_star():
    crit = critical_a_star(0.28, 0.08)
    assert crit == pytest.approx(0.993385, abs=1e-6)
    assert abs(normal_denominator(crit, 0.28, 0.08)) < 1e-12
    assert normal_denominator(crit - 1e-6, 0.28, 0.08) > 0
    assert normal_denominator(min(crit + 1e-6, 1.0), 0.28, 0.08) < 0
    assert critical_a_star(0.28, 0.0) == 1.0
    # a larger psi moves the singularity further below 1
    assert critical_a_star(0.28, 0.2) < crit


def test_springs_positive_below_critical_and_blow_up_at_it():
    s = np.linspace(0.05, critical_a_star(0.28, 0.08) - 1e-9, 200)
    k = spring_constants(s, np.ones_like(s), Material())
    for arr in k:
        assert np.all(np.isfinite(arr)) and np.all(arr > 0)
    assert k[0][-1] / k[0][-2] > 10  # k_n diverges as the denominator vanishes

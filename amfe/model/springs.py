"""The four bond springs of paper eqs. (1)-(4) (Liu et al. / Gopal).

All functions are vectorised over bonds. Inputs: contact radius ``a`` (M,) [m],
effective radius ``R`` (M,) [m] with 1/R = 1/R_i + 1/R_j, and a* = a / R (M,).
Outputs in SI: k_n, k_t [N/m]; kappa_n, kappa_t [N m].
"""
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from amfe.model.material import Material


def _numerator(a_star, nu):
    # 1 + a* [pi/6 (1 - nu^2)(1 + 2a*) - a*]
    return 1.0 + a_star * _bracket(a_star, nu)


def _bracket(a_star, nu):
    return np.pi / 6.0 * (1.0 - nu**2) * (1.0 + 2.0 * a_star) - a_star


def normal_denominator(a_star, nu, psi):
    """sqrt(1 - a*^2) - psi (a* + a*^2 [...]): the k_n and kappa_t denominator.

    It vanishes at :func:`critical_a_star`, slightly below a* = 1, and is
    negative beyond: a bond there has no physical spring.
    """
    a_star = np.asarray(a_star, dtype=float)
    return np.sqrt(1.0 - a_star**2) - psi * (a_star + a_star**2 * _bracket(a_star, nu))


A_STAR_MARGIN = 1e-10
"""Bonds closer than this to the critical a* are refused like those past it:
k_n there exceeds ~5e8 times a typical bond's, and the constants' error grows
as rtol times that contrast (measured: 7e-5 at crit - 1e-13 with rtol 1e-8,
where even a direct solve keeps only ~3e-7); see docs/hard_cases.md."""


@lru_cache(maxsize=64)
def critical_a_star(nu, psi):
    """The a* in (0, 1) where the k_n / kappa_t denominator reaches zero.

    0.99340... for nu = 0.28, psi = 0.08. With psi = 0 it is 1 exactly.
    """
    if psi == 0.0:
        return 1.0
    return float(brentq(lambda s: float(normal_denominator(s, nu, psi)), 0.5, 1.0,
                        xtol=1e-15, rtol=1e-15))


def spring_constants(a, R, material: Material):
    """k_n, k_t, kappa_n, kappa_t (each (M,)) for contact radii a and effective radii R.

    Assumes 0 < a* = a/R < critical_a_star; :func:`amfe.model.bonds.bond_springs`
    checks that before calling.
    """
    E, nu, psi = material.E, material.nu, material.psi
    a = np.asarray(a, dtype=float)
    R = np.asarray(R, dtype=float)
    s = a / R
    num = _numerator(s, nu)
    root = np.sqrt(1.0 - s**2)
    den = normal_denominator(s, nu, psi)
    k_n = E * a / (1.0 - nu**2) * num / den
    k_t = 2.0 * E * a / ((2.0 - nu) * (1.0 + nu)) * num / root
    kappa_n = 8.0 * E * R**3 * s**3 / ((2.0 - nu) * (1.0 + nu)) * num / root
    kappa_t = 2.0 * E * R**3 * s**3 / (1.0 - nu**2) * num / den
    return k_n, k_t, kappa_n, kappa_t

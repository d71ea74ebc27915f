"""The four bond springs of paper eqs. (1)-(4) (Liu et al. / Gopal), in one place.

All functions are vectorised over bonds. Inputs: contact radius ``a`` (M,) [m],
effective radius ``R`` (M,) [m] with 1/R = 1/R_i + 1/R_j, and a* = a / R (M,).
Outputs in SI: k_n, k_t [N/m]; kappa_n, kappa_t [N m].

A spring model (:data:`SPRING_MODELS`) is two plain functions: ``coefficients``
(Material -> tuple of floats, run once per material in Python) and ``springs``
(a, R, coefficients -> (k_n, k_t, kappa_n, kappa_t)). ``springs`` and the
helpers it calls use only arithmetic, ``**`` and np.sqrt, the same on numpy
arrays and on floats, so the numba kernel of the bond image
(amfe.dataset._jit) compiles these very functions and gives the same floats
bit for bit. Cubes are written as products (``R * R * R``): a power is not the
same floats on both sides (numba's ``**3`` multiplies; its ``**3.0`` calls the C
library's pow, which numpy 1.24's own power loop differs from in the last bit on
about a quarter of the values). A second model is a second entry here; the
kernel reads the table.
"""
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from amfe.errors import AmfeError
from amfe.model.material import Material


def _paper_parts(s, k_br, psi):
    """(Num, sqrt(1 - a*^2), Den) of eqs. 1-4 at a* = s; k_br = pi/6 (1 - nu^2).

    bracket = pi/6 (1 - nu^2)(1 + 2a*) - a*;  Num = 1 + a* bracket;
    Den = sqrt(1 - a*^2) - psi (a* + a*^2 bracket).
    """
    bracket = k_br * (1.0 + 2.0 * s) - s
    root = np.sqrt(1.0 - s * s)
    return 1.0 + s * bracket, root, root - psi * (s + s * s * bracket)


def paper_coefficients(material: Material):
    """The material's constants of eqs. 1-4:
    (E, psi, 1 - nu^2, pi/6 (1 - nu^2), (2 - nu)(1 + nu))."""
    nu = material.nu
    return (material.E, material.psi, 1.0 - nu**2, np.pi / 6.0 * (1.0 - nu**2),
            (2.0 - nu) * (1.0 + nu))


def paper_springs(a, R, coef):
    """k_n, k_t, kappa_n, kappa_t of paper eqs. 1-4 (docs/model.md, section 3).

    a, R: arrays or floats [m]; coef: :func:`paper_coefficients`.
    """
    E, psi, one_m_nu2, k_br, two_m_nu_one_p_nu = coef
    s = a / R
    num, root, den = _paper_parts(s, k_br, psi)
    k_n = E * a / one_m_nu2 * num / den
    k_t = 2.0 * E * a / two_m_nu_one_p_nu * num / root
    cubes = (R * R * R) * (s * s * s)
    kappa_n = 8.0 * E * cubes / two_m_nu_one_p_nu * num / root
    kappa_t = 2.0 * E * cubes / one_m_nu2 * num / den
    return k_n, k_t, kappa_n, kappa_t


@dataclass(frozen=True)
class SpringModel:
    """A bond-spring model: coefficients(material) -> tuple of floats, once per material;
    springs(a, R, coefficients) -> (k_n, k_t, kappa_n, kappa_t), numpy or numba alike;
    helpers: the plain functions springs calls (numba compiles them with it)."""

    name: str
    coefficients: Callable
    springs: Callable
    helpers: tuple = ()


SPRING_MODELS = {"paper": SpringModel("paper", paper_coefficients, paper_springs, (_paper_parts,))}
"""The spring models by name; the paper's eqs. 1-4 are the default."""


def spring_model(name="paper") -> SpringModel:
    """The :class:`SpringModel` called ``name``; AmfeError for an unknown name."""
    try:
        return SPRING_MODELS[name]
    except (KeyError, TypeError):
        raise AmfeError(f"unknown spring model {name!r}; choose one of "
                        f"{', '.join(SPRING_MODELS)}") from None


def normal_denominator(a_star, nu, psi):
    """sqrt(1 - a*^2) - psi (a* + a*^2 [...]): the k_n and kappa_t denominator.

    It vanishes at :func:`critical_a_star`, slightly below a* = 1, and is
    negative beyond: a bond there has no physical spring.
    """
    a_star = np.asarray(a_star, dtype=float)
    return _paper_parts(a_star, np.pi / 6.0 * (1.0 - nu**2), psi)[2]


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


def spring_constants(a, R, material: Material, springs: str = "paper"):
    """k_n, k_t, kappa_n, kappa_t (each (M,)) for contact radii a and effective radii R.

    ``springs`` names an entry of :data:`SPRING_MODELS`. Assumes 0 < a* = a/R <
    critical_a_star; :func:`amfe.model.bonds.bond_springs` checks that before calling.
    """
    chosen = spring_model(springs)
    a = np.asarray(a, dtype=float)
    R = np.asarray(R, dtype=float)
    return chosen.springs(a, R, chosen.coefficients(material))

"""Particle material (paper Table 1) in SI units."""
from dataclasses import dataclass, asdict

from amfe.errors import AmfeError


@dataclass(frozen=True)
class Material:
    """Elastic particle material.

    E: Young's modulus [Pa]; nu: Poisson's ratio [-]; psi: geometric factor of
    the k_n and kappa_t springs (paper eqs. 1 and 4) [-]; density [kg/m^3].
    """

    E: float = 210e9
    nu: float = 0.28
    psi: float = 0.08
    density: float = 7800.0

    def __post_init__(self):
        if not (self.E > 0 and abs(self.E) != float("inf")):
            raise AmfeError(f"Young's modulus must be positive and finite, got E={self.E}")
        if not (-1.0 < self.nu < 0.5):
            raise AmfeError(f"Poisson's ratio must lie in (-1, 0.5), got nu={self.nu}")
        if not (0.0 <= self.psi < 1.0):
            raise AmfeError(f"psi must lie in [0, 1), got psi={self.psi}")

    def asdict(self):
        return asdict(self)


STEEL = Material()
"""The paper's powder (Table 1): E = 210 GPa, nu = 0.28, psi = 0.08, 7800 kg/m^3."""

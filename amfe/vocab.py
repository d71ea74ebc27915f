"""amfe's names, defined once: the elastic constants and the load cases.

The Voigt order is xx, yy, zz, yz, xz, xy with engineering shear strains
(docs/model.md, section 5). The Poisson ratios follow nu_ij = -S_ji / S_ii:
lateral strain in j over axial strain in i under uniaxial stress in i.
"""

#: Voigt index pairs (i, j) of the six strain and stress components.
VOIGT_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))

#: The six load cases, one per unit macro-strain (or macro-stress), in Voigt order.
CASE_NAMES = ("xx", "yy", "zz", "yz", "xz", "xy")

#: The six constants a data-set label and the surrogate hold, in label order.
LABEL_NAMES = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy")

#: Every constant a homogenization reports: the labels, then the shear moduli.
CONSTANT_NAMES = LABEL_NAMES + ("G_yz", "G_xz", "G_xy")

#: Units of the constants (moduli in Pa, ratios dimensionless).
CONSTANT_UNITS = {name: ("1" if name.startswith("nu") else "Pa") for name in CONSTANT_NAMES}

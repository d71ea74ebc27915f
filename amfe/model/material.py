"""Particle material (paper Table 1) in SI units, and where a solve's material comes from.

Only E, nu and psi enter the springs (paper eqs. 1-4); the density does not.
A bed file's elastic material (attributes material_E, material_nu,
material_psi) is therefore complete or absent: :func:`material_from_attrs`
refuses a partial one, naming what is missing, instead of falling back to
steel. :func:`resolve_material` adds values given explicitly (the command
line's --E, --nu, --psi) and says where each came from.
:func:`check_material_names` refuses an attribute amfe would not read but a
reader would take for the material (material_e, Material_NU, E): ignored, it
would leave the bed solved as steel.
"""
import math
from dataclasses import asdict, dataclass

import numpy as np

from amfe.errors import AmfeError

ELASTIC = ("E", "nu", "psi")
"""The material constants that enter the stiffness."""
SOURCE_FILE, SOURCE_DEFAULT, SOURCE_GIVEN = "bed file", "default (steel)", "command line"


def real_number(name, value):
    """``value`` as a float if it is a real number (not a bool, str or sequence), else AmfeError."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                    np.floating)):
        raise AmfeError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    return float(value)


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
        for name in ("E", "nu", "psi", "density"):
            object.__setattr__(self, name, real_number(f"the material's {name}",
                                                       getattr(self, name)))
        if not (self.E > 0 and math.isfinite(self.E)):
            raise AmfeError(f"Young's modulus must be positive and finite, got E={self.E}")
        if not (-1.0 < self.nu < 0.5):
            raise AmfeError(f"Poisson's ratio must lie in (-1, 0.5), got nu={self.nu}")
        if not (0.0 <= self.psi < 1.0):
            raise AmfeError(f"psi must lie in [0, 1), got psi={self.psi}")
        if not (self.density > 0 and math.isfinite(self.density)):
            raise AmfeError(f"the density must be positive and finite, got {self.density}")

    def asdict(self) -> dict:
        return asdict(self)


STEEL = Material()
"""The paper's powder (Table 1): E = 210 GPa, nu = 0.28, psi = 0.08, 7800 kg/m^3."""


MATERIAL_ATTRS = tuple(f"material_{k}" for k in ELASTIC + ("density",))
"""The bed attributes that hold the material, spelt exactly so (the case matters)."""


def _squash(name):
    """``name`` lower-cased without separators: 'Material-E' and 'material_e' -> 'materiale'."""
    return "".join(ch for ch in str(name).lower() if ch.isalnum())


# squashed look-alike -> the attribute meant ("E" alone is a common name for the modulus)
_LOOK_ALIKES = {**{_squash(k): k for k in MATERIAL_ATTRS},
                **{_squash(k): f"material_{k}" for k in ELASTIC}}


def check_material_names(attrs, where="the bed"):
    """AmfeError for attributes of ``attrs`` that look like the material but are not read.

    That is a spelling of material_E, material_nu, material_psi or
    material_density other than the exact one (another case, '-' or no
    separator, or E, nu, psi without the prefix), or another number named
    material*. amfe reads the exact names only; such an attribute would be
    ignored and the bed solved with steel's values (or the file's other ones).
    The message names every such attribute and the spelling meant.
    """
    meant = {k: _LOOK_ALIKES[_squash(k)] for k in sorted(attrs)
             if k not in MATERIAL_ATTRS and _squash(k) in _LOOK_ALIKES}
    if meant:
        raise AmfeError(f"{where}: amfe reads the material from attributes spelt exactly "
                        f"{', '.join(MATERIAL_ATTRS)} (the case matters) and would solve this bed "
                        f"without {', '.join(repr(k) for k in meant)}: rename "
                        + ", ".join(f"{k!r} to {v!r}" for k, v in meant.items()))
    for key in sorted(attrs):
        value = attrs[key]
        numeric = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
            value, (bool, np.bool_))
        if numeric and key not in MATERIAL_ATTRS and _squash(key).startswith("material"):
            raise AmfeError(f"{where}: bed attribute {key!r} is not a material constant amfe "
                            f"reads ({', '.join(MATERIAL_ATTRS)}), so it would have no effect; "
                            "rename or delete it")


def _attr(attrs, key):
    return real_number(f"bed attribute {key}", attrs[key])


def resolve_material(attrs=None, given=None, default=STEEL, given_source=SOURCE_GIVEN):
    """The material of a solve and a record of where it came from.

    attrs: a bed's attributes (material_E, material_nu, material_psi and,
    optionally, material_density); given: explicit values {"E": Pa, "nu": -,
    "psi": -} (None entries ignored), which override the file's. The file's
    elastic material must be complete or absent, unless ``given`` supplies
    what it lacks. Returns (Material, record) with record = {"E", "nu",
    "psi", "source"}: source is "bed file", "default (steel)",
    ``given_source`` ("command line"), or, when mixed, e.g. "command line (E);
    bed file (nu, psi)".
    Raises AmfeError naming missing or malformed attributes, and misspelt
    ones (:func:`check_material_names`).
    """
    attrs = attrs or {}
    check_material_names(attrs)
    given = {k: real_number(k, v) for k, v in (given or {}).items() if v is not None}
    unknown = set(given) - set(ELASTIC)
    if unknown:
        raise AmfeError(f"unknown material constants {sorted(unknown)}; give E, nu or psi")
    in_file = [k for k in ELASTIC if f"material_{k}" in attrs]
    missing = [k for k in ELASTIC if k not in in_file and k not in given]
    if in_file and missing:
        raise AmfeError(
            "the bed file's material is incomplete: it has "
            + ", ".join(f"material_{k}" for k in in_file) + " but not "
            + ", ".join(f"material_{k}" for k in missing)
            + "; E, nu and psi all enter the stiffness (the density does not), so give all "
            "three or none (none: steel), or supply the missing ones on the command line "
            "(--E, --nu, --psi)")
    values, sources = {}, {}
    for k in ELASTIC:
        if k in given:
            values[k], sources[k] = given[k], given_source
        elif k in in_file:
            values[k], sources[k] = _attr(attrs, f"material_{k}"), SOURCE_FILE
        else:
            values[k], sources[k] = getattr(default, k), SOURCE_DEFAULT
    density = (_attr(attrs, "material_density") if "material_density" in attrs and in_file
               else default.density)
    if not in_file and not given:
        return default, {**values, "source": SOURCE_DEFAULT}
    try:
        material = Material(**values, density=density)
    except AmfeError as exc:
        where = {s for s in sources.values()}
        raise AmfeError(f"{exc} (from the {' and the '.join(sorted(where))})") from None
    return material, {**values, "source": _describe(sources)}


def _describe(sources):
    """'bed file', or 'command line (E); bed file (nu, psi)' when the sources are mixed."""
    order = list(dict.fromkeys(sources[k] for k in ELASTIC))
    if len(order) == 1:
        return order[0]
    return "; ".join(f"{s} ({', '.join(k for k in ELASTIC if sources[k] == s)})" for s in order)


def material_from_attrs(attrs, default=STEEL):
    """The :class:`Material` a bed's attrs record, ``default`` if they record none."""
    return resolve_material(attrs, default=default)[0]


#: Handbook alloys of the test sets of issue 46 (E, nu from handbooks, psi the paper's 0.08;
#: docs/datasets.md, "Materials", gives the sources). Keyed by the name `amfe dataset
#: --materials` takes; only E, nu and psi enter the springs.
ALLOYS = {
    "316L": Material(E=193e9, nu=0.29, psi=0.08, density=8000.0),
    "Ti64": Material(E=113.8e9, nu=0.342, psi=0.08, density=4430.0),
    "IN718": Material(E=205e9, nu=0.294, psi=0.08, density=8190.0),
    "AlSi10Mg": Material(E=70e9, nu=0.33, psi=0.08, density=2670.0),
}

"""How to solve a bed: :class:`SolveOptions`, every option checked once, where it is made.

:func:`amfe.solvers.driver.homogenize_bed` takes a checked :class:`~amfe.model.bed.Bed`
and one ``SolveOptions``; :func:`amfe.homogenize` and the command line build it
from their keyword options at once, so a wrong type or value is refused before
any work, with an error that names the option. What can only be checked against
the bed or the ranks (the a* cap against the material, the memory, that every
rank holds the same) is checked by :mod:`amfe.solvers.inputs`.
"""
import math
from dataclasses import dataclass, field

import numpy as np

from amfe.errors import AmfeError
from amfe.model.conditions import condition_names
from amfe.model.continuum_springs import SPRING_CHOICES, ContinuumSprings
from amfe.model.material import Material
from amfe.model.memory import parse_size

#: --solver: "auto" picks per bed (amfe.solvers.choice).
SOLVER_NAMES = ("auto", "gamg", "cholesky")


def check_rtol(value, name="rtol"):
    """``value`` as a float in (0, 1) (a relative tolerance), else AmfeError."""
    try:
        rtol = float(value)
    except (TypeError, ValueError):
        rtol = math.nan
    if isinstance(value, bool) or not 0.0 < rtol < 1.0:
        raise AmfeError(f"{name} must lie in (0, 1), got {value!r}")
    return rtol


def check_flag(name, value):
    """``value`` as a bool if it is one (numpy's too), else AmfeError naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise AmfeError(f"{name} must be True or False, got {type(value).__name__} {value!r}")
    return bool(value)


def check_choice(name, value, choices):
    """``value`` if it is one of ``choices`` (str), else AmfeError naming ``name``."""
    if not isinstance(value, str) or value not in choices:
        what = "unknown boundary condition" if name == "bc" else "unknown value"
        raise AmfeError(f"{name}: {what} {value!r}; choose one of {', '.join(choices)}")
    return value


def check_petsc_options(name, options):
    """``options`` as a dict {str: str, number, bool or None}, else AmfeError naming ``name``.

    None gives {}. A key may carry PETSc's dash (``"-ksp_monitor"``); None or ""
    as the value sets a flag.
    """
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise AmfeError(f"{name} must be a dict of PETSc options such as {{'ksp_monitor': None}}, "
                        f"got {type(options).__name__} {options!r}")
    for key, value in options.items():
        if not isinstance(key, str) or not key.lstrip("-"):
            raise AmfeError(f"{name}: every key must be a PETSc option's name (a str), got {key!r}")
        if value is not None and not isinstance(value, (str, bool, int, float, np.number)):
            raise AmfeError(f"{name}: the value of {key!r} must be a str, a number, a bool or "
                            f"None, got {type(value).__name__} {value!r}")
    return dict(options)


def check_petsc_args(name, args):
    """``args`` as a tuple of str (a command line's PETSc options), else AmfeError.

    A single str is refused rather than split: ``"-ksp_max_it 1"`` would otherwise
    be one option of that name, and silently do nothing.
    """
    if args is None:
        return ()
    if isinstance(args, (str, bytes)) or not isinstance(args, (list, tuple)) or not all(
            isinstance(a, str) for a in args):
        raise AmfeError(f"{name} must be a list of str such as ['-ksp_max_it', '1'], got "
                        f"{type(args).__name__} {args!r}")
    return tuple(args)


def check_max_memory(value, name="max_memory"):
    """Bytes of a memory limit: None, a positive number, or a size such as "8G"; else AmfeError."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return parse_size(value)
        except AmfeError:
            raise AmfeError(f"{name} must be a positive number of bytes or a size such as "
                            f"8G, 500M or 1.5GiB, got {value!r}") from None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)) \
            or not (math.isfinite(float(value)) and value > 0):
        raise AmfeError(f"{name} must be a positive number of bytes or a size such as 8G, got "
                        f"{type(value).__name__} {value!r}")
    return float(value)


def check_max_it(value):
    """None or a positive int, else AmfeError."""
    if value is not None and (isinstance(value, (bool, np.bool_))
                              or not isinstance(value, (int, np.integer)) or value < 1):
        raise AmfeError(f"max_it must be a positive integer, got {value!r}")
    return None if value is None else int(value)


def check_a_star_cap_type(value):
    """None or a finite real number (its range, which needs the material, comes later)."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)) \
            or not math.isfinite(float(value)):
        raise AmfeError(f"a_star_cap must be a finite number or None, got {value!r}")
    return value


@dataclass(frozen=True)
class SolveOptions:
    """How to solve a bed (:func:`amfe.solvers.driver.homogenize_bed`), checked when made.

    bc: a registered condition (:mod:`amfe.model.conditions`); rtol: GAMG's relative
    tolerance in (0, 1) or None (the default of docs/model.md, section 5); solver: one of
    :data:`SOLVER_NAMES`; max_it: iteration limit or None; ksp_options: PETSc
    options of this solve only ({name: value}); petsc_args: PETSc command-line
    options (["-ksp_monitor"]) added to the database; accept_unconverged: keep
    a solve that misses its tolerance, with a warning; max_memory: bytes over
    all ranks (None: half the machines' memory; "8G" is read as a size);
    diagnose: per-case solver diagnostics; fields: return the per-case fields
    (True: on every rank, "root": on rank 0 only);
    a_star_cap: cap every bond's a* at this value (None: refuse near-critical
    bonds); material: the particles' :class:`Material` (None: the bed's, else
    steel) and material_source, what to call its origin in the result;
    nondimensional: False assembles in SI units (a benchmark's); box: V's box (Lx, Ly, Lz)
    [m] as the user states it (``--box``; None: the box rule of docs/model.md, section 5);
    springs: the bond springs, "paper" (eqs. 1-4) or "continuum" (docs/model.md, section 11;
    a :class:`~amfe.model.continuum_springs.ContinuumSprings` for a fit's trial values).
    """

    bc: str = "kubc"
    rtol: float = None
    solver: str = "auto"
    max_it: int = None
    ksp_options: dict = field(default_factory=dict)
    petsc_args: tuple = ()
    accept_unconverged: bool = False
    max_memory: float = None
    diagnose: bool = False
    fields: bool = False
    a_star_cap: float = None
    material: Material = None
    material_source: str = None
    nondimensional: bool = True
    box: tuple = None
    springs: object = "paper"

    def __post_init__(self):
        checked = {
            "bc": check_choice("bc", self.bc, condition_names()),
            "rtol": None if self.rtol is None else check_rtol(self.rtol),
            "solver": check_choice("solver", self.solver, SOLVER_NAMES),
            "max_it": check_max_it(self.max_it),
            "ksp_options": check_petsc_options("ksp_options", self.ksp_options),
            "petsc_args": check_petsc_args("petsc_args", self.petsc_args),
            "max_memory": check_max_memory(self.max_memory),
            "a_star_cap": check_a_star_cap_type(self.a_star_cap),
            "box": check_box_lengths(self.box),
            "springs": check_springs(self.springs),
        }
        for name in ("accept_unconverged", "diagnose", "nondimensional"):
            checked[name] = check_flag(name, getattr(self, name))
        # "root": the fields on rank 0 only, for the files the face writes there
        checked["fields"] = "root" if self.fields == "root" else check_flag("fields", self.fields)
        if self.material is not None and not isinstance(self.material, Material):
            raise AmfeError("material must be an amfe.Material or None, got "
                            f"{type(self.material).__name__}")
        if self.material_source is not None and not isinstance(self.material_source, str):
            raise AmfeError(f"material_source must be a str, got {self.material_source!r}")
        for name, value in checked.items():  # frozen: set the normalised values once
            object.__setattr__(self, name, value)


def check_springs(value):
    """``value`` if it names a spring model (or is a ContinuumSprings), else AmfeError."""
    if isinstance(value, ContinuumSprings):
        return value
    return check_choice("springs", value, SPRING_CHOICES)


def check_box_lengths(box):
    """(Lx, Ly, Lz) floats [m] of a given box, or None; AmfeError for anything but three
    positive finite lengths."""
    if box is None:
        return None
    try:
        L = tuple(float(v) for v in box)
    except (TypeError, ValueError):
        L = ()
    if len(L) != 3 or not all(math.isfinite(v) and v > 0 for v in L):
        raise AmfeError(f"box must be three positive lengths (Lx, Ly, Lz) in m, got {box!r}")
    return L

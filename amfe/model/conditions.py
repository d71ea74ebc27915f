"""The boundary conditions, one entry each: the one place that lists them (docs/model.md, 5, 9).

Each :class:`Condition` says what a solve under it needs, and every layer reads
it from :data:`CONDITIONS`: the options' and the command line's choices,
which components of the bond graph carry load (:mod:`amfe.model.frame`), the
load cases (its module's ``groups``), whether the fields hold a macro-strain or
a macro-stress (:mod:`amfe.io.fields`), which conditions ``--bc all`` and
``amfe dataset`` offer, and the names the result schema accepts. The
solver-side parts, the average that turns the solutions into C and the test
of whether that average is second order in the solver's error, are named as
``"module:function"`` (or given as functions) and looked up by the driver
(:func:`solver_part`), so the model layer imports nothing above it and the
driver holds no list of names.

Adding a condition: its own module (groups, and its carrying rule if new),
then one :func:`register` call, here for amfe's own.
"""
import importlib
from collections.abc import Callable
from dataclasses import dataclass

from amfe.errors import AmfeError
from amfe.model.carrying import kubc_carrying, mixed_carrying, periodic_carrying, subc_carrying
from amfe.model.kubc import kubc_groups
from amfe.model.mixed import mixed_groups
from amfe.model.periodic import periodic_groups
from amfe.model.subc import subc_groups


@dataclass(frozen=True)
class Condition:
    """One boundary condition.

    name: its --bc name. groups(frame) -> [Group]: the load cases, grouped by
    operator (:mod:`amfe.model.loadcase`). carrying(x, r, i, j, shift, box,
    labels) -> sorted ids of the load-carrying components (lengths in any one
    unit; :mod:`amfe.model.carrying`). periodic: solved on a periodic bed's
    torus (its attrs name the periods). average: the solver-side average,
    ``"module:function"`` or a function (frame, groups, u, moments, diagnose,
    cross, [strain_cross]) -> (C, V, stats). second_order: the solver-side test
    (frame, groups) -> bool that the average is second order in the solver's
    error (:mod:`amfe.solvers.correction`). hull_strain: C comes from the Bagi
    hull strain with its hull vertices prescribed (KUBC), so free hull vertices
    can be weighed or corrected. loads: "strain" or "stress", what each case
    applies (the fields record the macro-strain or the macro-stress). in_all:
    solved by ``--bc all``. datasets: offered by ``amfe dataset`` (its beds are
    not periodic). help: its line in the command line's help.
    """

    name: str
    groups: Callable
    carrying: Callable
    average: "str | Callable"
    second_order: "str | Callable"
    periodic: bool = False
    hull_strain: bool = False
    loads: str = "strain"
    in_all: bool = False
    datasets: bool = True
    help: str = ""


#: The registered conditions by name, in the order the help lists them.
CONDITIONS = {}


def register(condition: Condition) -> Condition:
    """Add ``condition`` to the table (replacing one of its name); returns it."""
    if not isinstance(condition, Condition):
        raise AmfeError(f"register: a Condition is needed, got {type(condition).__name__}")
    if condition.loads not in ("strain", "stress"):
        raise AmfeError(f"condition {condition.name!r}: loads must be 'strain' or 'stress'")
    CONDITIONS[condition.name] = condition
    return condition


def unregister(name: str) -> None:
    """Remove the condition ``name`` from the table (for a test's own conditions)."""
    CONDITIONS.pop(name, None)


def condition_names(*, datasets: bool = False) -> tuple:
    """The registered names (only those ``amfe dataset`` offers, with ``datasets``)."""
    return tuple(n for n, c in CONDITIONS.items() if c.datasets or not datasets)


def get_condition(name: str) -> Condition:
    """The condition called ``name``; AmfeError naming the known ones otherwise."""
    try:
        return CONDITIONS[name]
    except (KeyError, TypeError):
        raise AmfeError(f"bc: unknown boundary condition {name!r}; choose one of "
                        f"{', '.join(CONDITIONS)}") from None


def solver_part(part: "str | Callable") -> Callable:
    """A condition's solver-side part: the function itself, or the one ``"module:function"``
    names (imported when first asked for)."""
    if callable(part):
        return part
    module, _, name = part.partition(":")
    return getattr(importlib.import_module(module), name)


register(Condition(
    "kubc", kubc_groups, kubc_carrying, "amfe.solvers.driver:bagi_average",
    "amfe.solvers.correction:second_order_kubc", hull_strain=True, in_all=True,
    help="six unit macro-strains on the boundary, one operator (default)"))
register(Condition(
    "mixed", mixed_groups, mixed_carrying, "amfe.solvers.driver:bagi_average",
    "amfe.solvers.correction:never",
    help="the paper's figure-2 experiments, prescribed displacements on one pair of faces, "
         "traction-free elsewhere, six operators"))
register(Condition(
    "subc", subc_groups, subc_carrying, "amfe.model.subc:subc_average",
    "amfe.solvers.correction:second_order_loads", loads="stress", in_all=True,
    help="six unit macro-stresses as loads on the boundary layer"))
register(Condition(
    "periodic", periodic_groups, periodic_carrying, "amfe.model.periodic:periodic_average",
    "amfe.solvers.correction:second_order_loads", periodic=True, in_all=True, datasets=False,
    help="a periodic bed (amfe pack --periodic) on its torus"))

"""amfe.predict: the surrogate's constants of beds from Python, as ``amfe predict`` gives them.

>>> p = amfe.predict("bed.h5")                      # doctest: +SKIP
>>> p.properties["Ex"], p.intervals["Ex"], p.flagged   # doctest: +SKIP

The records are built by the command's own code (amfe.cli.predict_core), so
``amfe.predict(beds)[k].to_dict()`` is bed k's record in ``amfe predict -o``'s
``beds``, number for number.
"""
import os
import time
from types import SimpleNamespace
from typing import TYPE_CHECKING

from amfe.cli.predict_common import check_springs
from amfe.cli.predict_core import predict_records
from amfe.errors import AmfeError
from amfe.model.material import Material

if TYPE_CHECKING:   # the type only: torch stays unloaded until a prediction
    from amfe.training.prediction import Prediction


def predict(beds: "object | str | os.PathLike | list", *, fallback: bool = False,
            stiffness: bool = False, model: "str | os.PathLike | None" = None,
            threshold: float | None = None, check: bool = False,
            petsc_args: tuple = (), material: "dict | object | None" = None,
            springs: str | None = None,
            flag_share: float | None = None) -> "Prediction | list[Prediction]":
    """Predict each bed's elastic constants with the shipped model for its size and material.

    beds: a bed file's path, a :class:`~amfe.model.bed.Bed`, or a list of them.
    fallback: solve (PETSc) a bed that is flagged or cannot be predicted; stiffness: the
    shipped full-stiffness model (C and the shear moduli too); model: a checkpoint for every
    bed instead of the shipped ones; threshold: the spread flag's threshold (default: the
    model's); check: also solve every bed; material: an :class:`~amfe.Material` or a dict of
    E [Pa], nu, psi for every bed, instead of its file's (as ``amfe predict --E --nu --psi``;
    it picks the route and is what a fallback solves); springs: "continuum" picks the shipped
    model of continuum-spring labels (0.6 mm beds; as ``amfe predict --springs``), "paper"
    the paper springs' (None: the paper's, or ``model``'s own); flag_share: the share of its
    calibration beds that the 0.6 mm model's risk flag flags (as ``amfe predict
    --flag-share``; None: the file's 0.19; docs/surrogate.md, "The flag"). Returns a
    :class:`~amfe.training.prediction.Prediction` for one bed, a list for a list; a bed that
    cannot be predicted gets source "failed" and its ``error`` (never an exception).
    """
    from amfe.training.prediction import Prediction  # noqa: TID253 (torch only when called)
    if stiffness and model:
        raise AmfeError("give model or stiffness, not both: stiffness picks the shipped "
                        "full-stiffness model")
    one = isinstance(beds, (str, os.PathLike)) or hasattr(beds, "centers")
    items = [beds] if one else list(beds)
    args = SimpleNamespace(model=None if model is None else os.fspath(model),
                           stiffness=stiffness, fallback=fallback, check=check,
                           threshold=threshold, petsc_args=list(petsc_args),
                           material=_given(material), material_source="argument",
                           springs=check_springs(springs, stiffness),
                           flag_share=_share(flag_share))
    records, _ = predict_records(args, items, {}, time.perf_counter())
    out = [Prediction(record) for record, _ in records]
    return out[0] if one else out


def _share(value):
    """``flag_share`` checked: None or a number strictly between 0 and 1."""
    if value is None:
        return None
    from amfe.training.flagrisk import check_share
    return check_share(value)


def _given(material):
    """{E, nu, psi} given for every bed (None: each bed's own)."""
    if material is None or isinstance(material, dict):
        return material or None
    if isinstance(material, Material):     # as amfe.homogenize takes it
        return {k: getattr(material, k) for k in ("E", "nu", "psi")}
    raise AmfeError("predict: material must be an amfe.Material or a dict of E, nu, psi; got "
                    f"{type(material).__name__}")

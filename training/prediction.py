"""One bed's prediction as a small result object (issue 46, item 4), and the E scaling.

:class:`Prediction` wraps the record ``amfe predict`` writes for a bed (one item of
its JSON's ``beds``): the Python face :func:`amfe.predict` and the command line build
it the same way, so ``Prediction.to_dict()`` is that record, number for number.

A bed whose material differs from the model's only in E is predicted by scaling the
moduli by E_bed / E_model (:func:`scale_moduli`): every spring is E times a function of
a*, R, nu and psi (docs/model.md), so Ex, Ey, Ez, the shear moduli and C scale exactly
and the Poisson ratios do not change.
"""
import json
import math
import os

from amfe.io.atomic import write_json

MODULI6 = (0, 1, 2)            # Ex, Ey, Ez in the six constants
MODULI9 = (0, 1, 2, 6, 7, 8)   # ... and G_yz, G_xz, G_xy in the nine


def scale_moduli(res, factor):
    """Scale a Surrogate.predict result's moduli in place by ``factor`` (E_bed / E_model):
    mean (n, 6), constants9 (n, 9) and stiffness C (n, 6, 6); relative spreads unchanged."""
    if factor == 1.0:
        return res
    res["mean"][:, list(MODULI6)] *= factor
    if "constants9" in res:
        res["constants9"][:, list(MODULI9)] *= factor
    if "stiffness" in res:
        res["stiffness"] *= factor
    return res


def scale_intervals(bars, factor):
    """An interval block (amfe.training.conformal.interval_block) with its moduli's bounds
    scaled by ``factor``; ratios' bounds unchanged."""
    if bars is None or factor == 1.0 or not bars.get("intervals"):
        return bars
    bars = dict(bars)
    bars["intervals"] = {k: ([v * factor for v in lo_hi] if k.startswith(("E", "G"))
                             else list(lo_hi)) for k, lo_hi in bars["intervals"].items()}
    return bars


def failed_record(path, error, size=None, times=None):
    """The record of a bed that could not be predicted: source "failed" and the reason."""
    return {"bed": None if path is None else str(path), "size": size,
            "properties": None, "intervals": None, "coverage": None, "flagged": True,
            "flag_reasons": ["failed"], "source": "failed", "error": str(error),
            "model": None, "timings": times or {}}


class Prediction:
    """One bed's predicted constants: ``properties`` {name: value} (Pa, -; the six, and with
    --stiffness the shear moduli too), ``intervals`` {name: [lo, hi]} or None, ``coverage``,
    ``flagged``, ``flag_reasons``, ``source`` ("surrogate", "solver" or "failed"), ``error``
    (why a failed bed was not predicted), ``bed`` (its path or None), ``size`` [m],
    ``material``, ``model`` (the checkpoint's path), ``timings`` [s], ``notes``."""

    def __init__(self, record: dict) -> None:
        self.record = record

    def __getattr__(self, name):
        record = self.__dict__.get("record", {})
        if name in ("bed", "size", "material", "properties", "intervals", "coverage",
                    "flagged", "flag_reasons", "source", "error", "model", "timings", "notes"):
            return record.get(name)
        raise AttributeError(name)

    def to_dict(self) -> dict:
        """The record, as in ``amfe predict -o``'s ``beds`` (a copy)."""
        return json.loads(json.dumps(self.record))

    def to_json(self, path: "str | os.PathLike") -> None:
        """Write the record as JSON (atomically)."""
        write_json(path, self.record)

    def __repr__(self) -> str:
        if self.source == "failed":
            return f"Prediction({self.bed!r}: failed: {self.error})"
        props = self.properties or {}
        shown = ", ".join(f"{k}={v / 1e9:.4g} GPa" if k.startswith(("E", "G")) else
                          f"{k}={v:.4g}" for k, v in props.items()
                          if v is not None and math.isfinite(v))
        flag = f"flagged ({', '.join(self.flag_reasons)})" if self.flagged else "not flagged"
        return f"Prediction({self.bed!r}, {self.source}: {shown}; {flag})"

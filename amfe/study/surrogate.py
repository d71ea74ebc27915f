"""A sweep row from the surrogate: the six constants, their intervals and the flag.

The rows are ``amfe predict``'s own records (amfe.cli.predict_core.predict_records:
the shipped model or the route for the bed's size, thickness and material, the
flag and the intervals), so a sweep's surrogate row says what ``amfe predict``
says of the same bed. Its solid fraction is the mean of the bed's fill image:
the volume fraction of the imaged box, which is V's box for a generated bed,
measured as amfe.dataset.density measures it.
"""
import math
import time
from types import SimpleNamespace

from amfe.cli.predict_core import predict_records
from amfe.dataset.pixelkernel import warm

#: predict_records' options for a sweep: no solve (the sweep solves its flagged beds itself).
_ARGS = SimpleNamespace(model=None, stiffness=False, fallback=False, check=False,
                        threshold=None, petsc_args=[])


def predict_rows(cache, beds, springs="paper", flag_share=None):
    """[{constants, source, flagged, flag_reasons, route, <name>_lo/_hi, solid_fraction}] of
    ``beds``; ``cache``: kept between calls (the loaded models); springs: "continuum" takes
    the continuum springs' model (a bed it does not cover gets a failed row, which a
    fallback sweep solves); flag_share: as amfe predict's --flag-share (None: the model's)."""
    if not cache:
        warm()   # numba's imaging where no C kernel builds: 10x faster on small beds
    args = SimpleNamespace(**vars(_ARGS), springs=None if springs == "paper" else springs,
                           flag_share=flag_share)
    records, _ = predict_records(args, beds, {}, time.perf_counter(), cache)
    return [_row(out) for out, _ in records]


def _row(out):
    if out["source"] == "failed":
        return {"source": "failed", "error": out["error"], "flagged": True,
                "flag_reasons": "failed"}
    row = {k: (v if v is not None and math.isfinite(v) else None)
           for k, v in out["properties"].items()}
    for name, (lo, hi) in (out.get("intervals") or {}).items():
        row[f"{name}_lo"], row[f"{name}_hi"] = lo, hi
    return {**row, "source": "surrogate", "flagged": bool(out["flagged"]),
            "flag_reasons": ",".join(out["flag_reasons"]),
            "solid_fraction": float(out["density"])}

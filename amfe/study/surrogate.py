"""A sweep row from the surrogate: the six constants, their intervals and the flag.

The model is the shipped one for the bed's size (amfe.training.shipped), loaded
once per size; the flag and the intervals are those ``amfe predict`` reports
(amfe.cli.predict: spread, fill, non-finite, and an interval wider than the
model's limit).
"""
import math

from amfe.cli.predict import flag_reasons, interval_of
from amfe.dataset.pixelkernel import warm
from amfe.training.predict import Surrogate, as_properties
from amfe.training.shipped import shipped_model_for


def predict_rows(cache, beds):
    """[{constants, source, flagged, flag_reasons, <name>_lo/_hi}] of ``beds`` (one network
    pass per model); ``cache``: {model path: Surrogate}, filled as models are loaded."""
    paths = [shipped_model_for(bed) for bed in beds]
    out = [None] * len(beds)
    for path in dict.fromkeys(paths):
        if path not in cache:
            warm()   # the compiled imaging for every bed of the sweep: 10x faster on small ones
            cache[path] = Surrogate.load(path)
        sur = cache[path]
        mine = [i for i, p in enumerate(paths) if p == path]
        for i, (res, _, _) in zip(mine, sur.predict_beds([beds[i] for i in mine])):
            out[i] = _row(sur, beds[i], res)
    return out


def _row(sur, bed, res):
    reasons = flag_reasons(res, sur.threshold, sur.n_members)
    bars = interval_of(sur, bed, res) if "non-finite" not in reasons else None
    if bars is not None and bars["interval_flag"]:
        reasons.append("interval")
    row = {k: (v if math.isfinite(v) else None) for k, v in as_properties(res["mean"][0]).items()}
    for name, (lo, hi) in ((bars or {}).get("intervals") or {}).items():
        row[f"{name}_lo"], row[f"{name}_hi"] = lo, hi
    return {**row, "source": "surrogate", "flagged": bool(reasons),
            "flag_reasons": ",".join(reasons)}

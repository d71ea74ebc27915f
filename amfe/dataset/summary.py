"""What a data set holds, as text: failures grouped by reason, the density histogram, a summary."""
import re
import time

import numpy as np

from amfe.dataset.parts import LABEL_RULES, STATUS_OK, label_rule
from amfe.vocab import LABEL_NAMES


def reason_key(reason):
    """A failure reason with its numbers blanked, for grouping similar failures."""
    return re.sub(r"[-+]?\d+(\.\d+)?([eE][-+]?\d+)?", "#", str(reason)).strip()[:120]


def failure_groups(status, reasons):
    """[(count, reason key)] of the failed records, most frequent first."""
    groups = {}
    for s, r in zip(status, reasons):
        if int(s) != STATUS_OK:
            key = reason_key(r)
            groups[key] = groups.get(key, 0) + 1
    return sorted(((n, k) for k, n in groups.items()), key=lambda t: (-t[0], t[1]))


def density_histogram(density, bins=10, width=40):
    """Text histogram of the finite packing densities (one line per bin)."""
    d = np.asarray(density, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return "packing density: no values"
    lo, hi = float(d.min()), float(d.max())
    if hi - lo < 1e-9:
        return f"packing density: all {d.size} records at {lo:.3f}"
    counts, edges = np.histogram(d, bins=bins, range=(lo, hi))
    peak = counts.max()
    lines = [f"packing density (mean of the image), {d.size} records, "
             f"min {lo:.3f} median {np.median(d):.3f} max {hi:.3f}:"]
    for c, a, b in zip(counts, edges[:-1], edges[1:]):
        bar = "#" * int(round(width * c / peak)) if peak else ""
        lines.append(f"  {a:.3f}-{b:.3f} {c:6d} {bar}")
    return "\n".join(lines)


def summary_text(data, attrs):
    """A few lines: records, ok/failed with grouped reasons, label ranges, density histogram."""
    status = data["status"]
    M = status.shape[0]
    ok = status == STATUS_OK
    lines = [f"{M} records (scale {attrs.get('scale')}, seed {attrs.get('seed')}, amfe "
             f"{attrs.get('amfe_version')}, created {attrs.get('created')}): {int(ok.sum())} ok, "
             f"{int(M - ok.sum())} failed; images {'x'.join(map(str, data['images'].shape[1:]))}",
             f"  labels made under {LABEL_RULES[label_rule(attrs)]} (docs/model.md, section 5)"]
    if "material_spec" in attrs:
        p = data.get("params", {})
        spread = "".join(f"; {n} {np.nanmin(p[n]):.4g}-{np.nanmax(p[n]):.4g}" for n in ("nu", "psi")
                         if n in p and np.isfinite(p[n]).any())
        lines.append(f"  material: {attrs['material_spec']}{spread}")
    for n, key in failure_groups(status, data["reason"]):
        lines.append(f"  failed {n:5d} x {key}")
    if ok.any():
        lab = data["labels"][ok]
        for j, name in enumerate(LABEL_NAMES):
            scale, unit = (1e9, " GPa") if j < 3 else (1.0, "")
            v = lab[:, j] / scale
            lines.append(f"  {name:6s} min {v.min():9.4g}  median {np.median(v):9.4g}  "
                         f"max {v.max():9.4g}{unit}")
    lines.append(density_histogram(data["density"][ok] if ok.any() else data["density"]))
    return "\n".join(lines)


def _hms(seconds):
    s = int(round(seconds))
    return f"{s // 3600}h{s % 3600 // 60:02d}m{s % 60:02d}s" if s >= 3600 else \
        (f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{seconds:.1f}s")



def final_summary(output, data, attrs, run, t_start, ranks):
    """The closing summary of `amfe dataset`: {"lines": [...]} plus the figures it quotes."""
    status = data["status"]
    ok = int(np.sum(status == STATUS_OK))
    M = int(status.shape[0])
    groups = failure_groups(status, data["reason"])
    fails = "; ".join(f"{n} x {r}" for n, r in groups) if groups else "none"
    wall = time.perf_counter() - t_start
    res = {"complete_before": run is None, "records": M, "ok": ok, "failed": M - ok,
           "failures": groups, "seconds": wall, "ranks": ranks}
    if run is None:
        line = f"amfe dataset: {output}: {M} beds, {ok} ok, {M - ok} failed ({fails})"
    else:
        rate = run["done"] / wall * 3600.0 if wall > 0 else float("nan")
        share = run["solve"] / (wall * ranks) if wall > 0 else float("nan")
        res.update(done_this_run=run["done"], failed_this_run=run["failed"],
                   beds_per_hour=rate, solve_rank_seconds=run["solve"],
                   generate_rank_seconds=run["generate"], image_rank_seconds=run["image"],
                   busy_rank_seconds=run["busy"], work_seconds=run["work_seconds"])
        line = (f"amfe dataset: {output}: {M} beds, {ok} ok, {M - ok} failed ({fails}); this run "
                f"{run['done']} beds in {_hms(wall)} on {ranks} rank(s) = {rate:.0f} beds/hour "
                f"({rate / ranks:.0f} per core), {100 * share:.0f} % of rank time in the solver")
    res["lines"] = [line, density_histogram(data["density"][status == STATUS_OK])]
    return res

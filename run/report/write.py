"""Plots and markdown of the speed-against-error report (run/report/report.py) from its measured data.

write_report(data, out, sections) writes out/report.md, out/report_*.png and out/report.json
atomically and returns their paths. Nothing here measures: every number comes from ``data``.
"""
import json
import os

import numpy as np
from run.common import ROOT
from run.report.figures import _plt, _s, _save  # noqa: E402

from amfe.io.atomic import atomic_write  # noqa: E402
from amfe.training.plots import plain_log_axis, spread_labels  # noqa: E402  (no torch)

from run.report import measure as M  # noqa: E402
from run.report.sizes import section_sizes  # noqa: E402
from run.report.voxel_write import section_voxel  # noqa: E402

PHASES = ("generate", "bonds", "assemble", "setup", "solves", "averages")
FLOOR = 1e-16  # errors at round-off are drawn here on log axes


def _loglog(ax, xlabel, ylabel, title, handles=None, legend_title=None):
    """Log-log axes with labels, grid and legend (``handles``: extra legend keys)."""
    ax.set(xscale="log", yscale="log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(handles=ax.get_legend_handles_labels()[0] + (handles or []), fontsize=7,
              title=legend_title, title_fontsize=7)


def _key(label, **style):
    """A legend entry with no data: what a marker or line style means."""
    from matplotlib.lines import Line2D
    return Line2D([], [], label=label, **style)


RTOL_LABELS = "numbers at the points: solver rtol"

def _e(x):
    return f"{x:.1e}"


# ------------------------------------------------------------ sections

def section_accuracy(acc, out, md):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.8))
    for m in _methods(acc["runs"]):
        rs = [r for r in acc["runs"] if r["method"] == m]
        t = [r["seconds"] for r in rs]
        e = [max(r["error"], FLOOR) for r in rs]
        if rs[0]["rtol"] is None:
            ax.plot(t, e, "s", ms=9, label=m)
        else:
            ax.plot(t, e, "o-", label=m)
    front = M.pareto_front(acc["runs"])
    ax.plot([r["seconds"] for r in front], [max(r["error"], FLOOR) for r in front], "k--",
            lw=0.8, label="Pareto front")
    _loglog(ax, "preconditioner/factor set-up + six solves [s]",
            "max relative error of the nine constants [-]",
            f"{acc['n_particles']} particles, {acc['n_bonds']} bonds", legend_title=RTOL_LABELS)
    color = {ln.get_label(): ln.get_color() for ln in ax.lines}
    it = [r for r in acc["runs"] if r["rtol"] is not None]   # labels last: axes limits fixed
    spread_labels(ax, [(r["seconds"], max(r["error"], FLOOR)) for r in it],
                  [f"{r['rtol']:.0e}" for r in it], [color[r["method"]] for r in it], fontsize=6)
    paths = [_save(fig, os.path.join(out, "report_pareto.png"))]

    md += ["## 1. Solver accuracy against cost", "",
           f"Bed: {acc['bed']}: {acc['n_particles']} particles, {acc['n_bonds']} bonds, one rank. "
           "Reference: CG + GAMG at rtol 1e-12. Error: the largest relative difference of the "
           "nine constants (Ex, Ey, Ez, the three nu, the three G) from the reference. Time: "
           "preconditioner or factorisation set-up plus the six load-case solves; bonds and "
           f"assembly, the same for every method, take {_s(acc['common_seconds'])} more. "
           "scipy SuperLU factorises and solves the same KUBC problem outside PETSc "
           "(solvers/scipy_direct.py).", "",
           "![accuracy against cost](report_pareto.png)", "",
           "| method | rtol | iterations per case | time | max rel. error |",
           "|---|---|---|---|---|"]
    for r in acc["runs"]:
        rtol = "-" if r["rtol"] is None else f"{r['rtol']:.0e}"
        md.append(f"| {r['method']} | {rtol} | {r['iterations']:.1f} | {_s(r['seconds'])} | "
                  f"{_e(r['error'])} |")
    for m, why in acc["unavailable"].items():
        md.append(f"| {m} | - | - | not run | {why} |")
    rec = acc["recommended"]
    md += [""]
    gamg = {r["rtol"]: r for r in acc["runs"] if r["method"] == "CG + GAMG"}
    if rec:
        md.append(f"**Cheapest run within 1e-6 of the reference on this bed:** {rec['method']}"
                  + (f" at rtol {rec['rtol']:.0e}" if rec["rtol"] else "")
                  + f", {_s(rec['seconds'])}.")
    plain = {r["rtol"]: r for r in acc["runs"] if r["method"] == "CG + GAMG, uncorrected"}
    rd = acc.get("default_rtol")
    if rd in gamg and 1e-8 in plain:
        why = ("every hull vertex is prescribed, so the corrected constants are second order "
               "in the solver's error" if rd > 1e-8 else
               "some hull vertices are free, so the strain stays first order in the solver's "
               "error and the default stays 1e-8, corrected all the same")
        md.append(f"amfe's default on this bed is CG + GAMG at rtol {rd:.0e} with the "
                  f"second-order stress ({why}; docs/model.md section 5): "
                  f"{_e(gamg[rd]['error'])} from the reference in {gamg[rd]['iterations']:.1f} "
                  f"iterations per case. Uncorrected at rtol 1e-8 (the default before) it was "
                  f"{_e(plain[1e-8]['error'])} in {plain[1e-8]['iterations']:.1f}.")
    md.append("")
    growth = acc.get("growth") or []
    if growth:
        md += ["How the choice changes with the bed (fully scanned, 0.3 mm high, one rank; "
               "set-up + six solves; error against MUMPS):", "",
               "| base [mm] | particles | " + " | ".join(_methods(growth)) + " |",
               "|---|---|" + "---|" * len(_methods(growth))]
        for side in sorted({r["side_mm"] for r in growth}):
            rs = {r["method"]: r for r in growth if r["side_mm"] == side}
            n = next(iter(rs.values()))["n_particles"]
            md.append(f"| {side:g} | {n} | " + " | ".join(
                f"{_s(rs[m]['seconds'])} ({_e(rs[m]['error'])})" if m in rs else "-"
                for m in _methods(growth)) + " |")
        md.append("")
        big = max(r["side_mm"] for r in growth)
        rs = {r["method"]: r for r in growth if r["side_mm"] == big}
        if "CG + GAMG" in rs:
            direct = [r for m, r in rs.items() if m != "CG + GAMG"]
            if direct:
                fastest = min(direct, key=lambda r: r["seconds"])
                g = rs["CG + GAMG"]["seconds"]
                lead = (f"the factorisations' lead on small beds has turned into a loss "
                        f"({fastest['seconds'] / g:.1f}x GAMG's time)" if g < fastest["seconds"]
                        else f"a factorisation is still {g / fastest['seconds']:.1f}x faster at "
                        "this size, but its fill grows faster than the bed")
                md.append(f"**Recommended default: CG + GAMG at amfe's default rtol** (1e-5 with "
                          "the second-order stress, 1e-8 where the hull has free vertices). On "
                          "the largest of "
                          f"these beds it takes {_s(g)} against {_s(fastest['seconds'])} for "
                          f"the fastest factorisation ({fastest['method']}): {lead}. GAMG's "
                          "iterations stay flat and its time grows about linearly up to the "
                          "paper's full bed (section 2), it runs distributed, and its default "
                          "rtol holds the constants far below any error that matters here.")
        md.append("")
    return paths


def _methods(rows):
    out = []
    for r in rows:
        if r["method"] not in out:
            out.append(r["method"])
    return out


def section_scaling(rows, out, md):
    plt = _plt()
    ranks = sorted({r["ranks"] for r in rows})
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    fits = {}
    for k, nr in enumerate(ranks):
        rs = sorted([r for r in rows if r["ranks"] == nr], key=lambda r: r["n_particles"])
        n = [r["n_particles"] for r in rs]
        ls = "-" if k == 0 else "--"
        if k == 0:
            for ph in PHASES:
                a1.plot(n, [max(r[ph], 1e-5) for r in rs], "o" + ls, ms=3, label=ph)
        a1.plot(n, [r["total"] for r in rs], "k" + ls, lw=2, label=f"total, {nr} rank(s)")
        big = [r for r in rs if r["n_particles"] >= 3000] or rs
        if len(big) >= 2:
            fits[nr] = M.fit_exponent([r["n_particles"] for r in big], [r["total"] for r in big])
        a2.plot(n, [r["iterations"] for r in rs], "o" + ls, label=f"CG iterations, {nr} rank(s)")
        a2.plot(n, [r["matvecs_per_solve"] for r in rs], "s" + ls,
                label=f"solve / fine-level matvec, {nr} rank(s)")
    a1.set_xscale("log")
    a1.set_yscale("log")
    a1.set_xlabel("particles")
    a1.set_ylabel("time [s]")
    a1.set_title(f"phases on {ranks[0]} rank; total on "
                 + " and ".join(map(str, ranks)) + " ranks")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=7)
    a2.set_xscale("log")
    a2.set_xlabel("particles")
    a2.set_ylabel("count per load case [-]")
    a2.set_title("iterations and cost of a solve in matrix-vector products")
    a2.grid(True, which="both", alpha=0.3)
    a2.legend(fontsize=7)
    paths = [_save(fig, os.path.join(out, "report_scaling.png"))]

    md += ["## 2. Scaling", "",
           "Fully scanned beds, 0.3 mm high (three powder layers), square bases from "
           f"{min(r['side_mm'] for r in rows)} mm to {max(r['side_mm'] for r in rows)} mm "
           "(the paper's full bed is 3 mm). Each run is `mpirun -n RANKS` of this script; "
           "times are wall-clock on rank 0. 'solve / matvec': the time of one load-case solve "
           "over the time of one MatMult with the assembled fine-level AIJ matrix (the cost of "
           "a solve counted in fine-level matrix-vector products: CG's own products, GAMG's "
           "smoothing on every level, the restriction and interpolation).", "",
           "![scaling](report_scaling.png)", "",
           "| base [mm] | ranks | particles | bonds | " + " | ".join(PHASES)
           + " | total | iterations | solve / matvec |",
           "|" + "---|" * (len(PHASES) + 7)]
    for r in sorted(rows, key=lambda r: (r["ranks"], r["n_particles"])):
        md.append(f"| {r['side_mm']:g} | {r['ranks']} | {r['n_particles']} | {r['n_bonds']} | "
                  + " | ".join(f"{r[p]:.3g}" for p in PHASES)
                  + f" | {r['total']:.3g} | {r['iterations']:.1f} | {r['matvecs_per_solve']:.0f} |")
    md.append("")
    for nr, p in fits.items():
        md.append(f"- total time ~ n^{p:.2f} on {nr} rank(s) (least squares over beds of "
                  "3 000 particles and more).")
    same = _rank_invariance(rows)
    if same is not None:
        md.append(f"- the constants on {ranks[0]} and {ranks[-1]} ranks agree to {_e(same)} "
                  "(largest relative difference over the beds and the nine constants).")
    md.append("")
    return paths, fits, same


def _rank_invariance(rows):
    ranks = sorted({r["ranks"] for r in rows})
    if len(ranks) < 2:
        return None
    by = {(r["side_mm"], r["ranks"]): r for r in rows}
    diffs = [M.max_rel_error(by[(s, ranks[-1])]["properties"], by[(s, ranks[0])]["properties"])
             for (s, nr) in by if nr == ranks[0] and (s, ranks[-1]) in by]
    return max(diffs) if diffs else None


def section_surrogate(sur, out, md):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.8))
    pix = sur["pixelate_seconds"]
    for name, r in sur["networks"].items():
        t = 1e-3 * r["ms_per_bed"]
        ln = ax.plot([t], [100 * r["mean_error"]], "o", ms=8, label=r["description"])
        ax.plot([t + r.get("image_seconds", pix)], [100 * r["mean_error"]], "o", mfc="none",
                color=ln[0].get_color())
    s = sur["solver"]
    loose = [r for r in s if r["mean_error"] > 0]  # rtol 1e-8 is the labels' own solve: 0
    ax.plot([r["seconds"] for r in loose], [100 * r["mean_error"] for r in loose], "ks-",
            label="PETSc CG + GAMG")
    for r in s:
        if r["mean_error"] == 0:
            ax.axvline(r["seconds"], color="k", ls=":", lw=1,
                       label=f"solver at rtol {r['rtol']:.0e} (how the labels were made)")
    keys = [_key("network alone (filled)", ls="none", marker="o", color="grey"),
            _key("network + making its images", ls="none", marker="o", mfc="none", color="grey")]
    _loglog(ax, "time per bed on one core [s]", "mean relative error over the six labels",
            f"held-out beds ({sur['n_test']} for the networks)", keys, RTOL_LABELS)
    plain_log_axis(ax.yaxis, " %")
    spread_labels(ax, [(r["seconds"], 100 * r["mean_error"]) for r in loose],
                  [f"{r['rtol']:.0e}" for r in loose], fontsize=7)
    paths = [_save(fig, os.path.join(out, "report_surrogate.png"))]
    md += ["## 4. Surrogate against solver", "",
           f"Held-out beds: `{sur['test']}` ({sur['n_test']} beds, a data-set seed no network "
           "trained on). Networks: mean relative error over all of them, inference batched on "
           f"one torch thread (and two); pixelating a bed adds {_s(pix)}, its bond image "
           f"{_s(sur.get('bond_image_seconds', np.nan))} for the networks that read it (open "
           f"circles). Solver: the first {s[0]['beds']} of those beds regenerated from their "
           "seeds and solved on one core at each rtol, time from the bed's particles to its "
           "constants (bonds, assembly, set-up, solves, averages), error against the data set's "
           "labels (rtol 1e-8).", "",
           "![surrogate against solver](report_surrogate.png)", "",
           "| model | parameters | training | ms per bed (1 thread; 2) | mean error | Ex | Ey "
           "| Ez | nu_yz | nu_xz | nu_xy |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sur["networks"].values():
        md.append(f"| {r['description']} | {r['params']:,}" + (f" x {r['members']}"
                  if r["members"] > 1 else "") + f" | {_s(r['train_seconds'])}"
                  + (" of fine-tuning" if r.get("fine_tuned") else "") + " | "
                  f"{r['ms_per_bed']:.3f}; {r.get('ms_per_bed_2threads', np.nan):.3f} | "
                  f"{100 * r['mean_error']:.2f} % | "
                  + " | ".join(f"{100 * r['mre'][k]:.2f} %" for k in M.LABELS) + " |")
    for r in s:
        md.append(f"| solver, rtol {r['rtol']:.0e} | - | - | {1e3 * r['seconds']:.0f} | "
                  f"{100 * r['mean_error']:.1e} % (max {100 * r['max_error']:.1e} %) | "
                  + " | ".join("" for _ in M.LABELS) + " |")
    loose = [r for r in s if r["mean_error"] < min(
        (n["mean_error"] for n in sur["networks"].values()), default=1.0)]
    md.append("")
    if loose:
        r = max(loose, key=lambda r: r["rtol"])
        best = min(sur["networks"].values(), key=lambda n: n["mean_error"])
        md.append(f"The solver at rtol {r['rtol']:.0e} ({_s(r['seconds'])} per bed) is already "
                  f"more accurate than the best network ({best['description']}, "
                  f"{100 * best['mean_error']:.2f} %), which is "
                  f"{r['seconds'] / (1e-3 * best['ms_per_bed']):.0f}x faster batched and "
                  f"{r['seconds'] / (1e-3 * best['ms_per_bed'] + best.get('image_seconds', pix)):.0f}x "
                  "faster with its images. The networks miss issue 6's 2 % / 3 % targets "
                  "(docs/surrogate.md).")
    md.append("")
    return paths


def section_paper(data, md):
    P = {"small": None, "large": None, "pred": None, "err": None}
    sc = data.get("scaling") or []
    full = [r for r in sc if abs(r["side_mm"] - 3.0) < 1e-9]
    if full:
        P["large"] = min(full, key=lambda r: r["total"])
    sur = data.get("surrogate")
    if sur:
        s8 = [r for r in sur["solver"] if r["rtol"] == 1e-8]
        P["small"] = s8[0]["seconds"] if s8 else None
        # the shipped model when measured, else round 1's, else the volume-fraction ensemble
        net = next((sur["networks"][n] for n in ("shipped", "bonds", "ensemble")
                    if n in sur["networks"]),
                   None)
        if net:
            P["pred"], P["err"], P["net"] = net["ms_per_bed"], net["mean_error"], net["description"]
    rows = [("DEM of a 'small' structure (paper: unspecified size; amfe: a `small` data-set "
             "bed, 0.6 x 0.6 x 0.3 mm, one core)", _s(M_PAPER["small_structure_s"]),
             P["small"] and _s(P["small"]),
             P["small"] and f"{M_PAPER['small_structure_s'] / P['small']:.0f}x faster"),
            ("DEM of the full 3 x 3 x 0.3 mm bed" + (f" ({P['large']['n_particles']} particles, "
             f"{P['large']['ranks']} rank(s))" if P["large"] else ""),
             _s(M_PAPER["large_structure_s"]), P["large"] and _s(P["large"]["total"]),
             P["large"] and f"{M_PAPER['large_structure_s'] / P['large']['total']:.0f}x faster"),
            (f"CNN prediction per bed (amfe: {P.get('net') or 'the shipped model'}, batched, "
             "one thread)",
             f"{M_PAPER['prediction_ms']} ms", P["pred"] and f"{P['pred']:.3f} ms",
             P["pred"] and f"{M_PAPER['prediction_ms'] / P['pred']:.0f}x faster"),
            ("CNN mean error", "under 4 %", P["err"] and f"{100 * P['err']:.2f} %",
             P["err"] and ("better" if P["err"] < M_PAPER["error"] else
                           f"{P['err'] / M_PAPER['error']:.1f}x the paper's (worse)"))]
    md += ["## 5. Against the paper", "",
           "The paper's figures (section 7) beside amfe's from this run. The paper's errors are "
           "on its own labels and beds; amfe's on its held-out beds.", "",
           "| | paper | amfe | ratio |", "|---|---|---|---|"]
    for name, paper, amfe, ratio in rows:
        md.append(f"| {name} | {paper} | {amfe or 'not measured in this run'} | {ratio or '-'} |")
    md.append("")


M_PAPER = {"small_structure_s": 51 * 60, "large_structure_s": 6 * 3600 + 34 * 60,
           "prediction_ms": 37.24, "error": 0.04}


def write_report(data, out, sections):
    """Write report.md, report_*.png and report.json under ``out``; returns the paths."""
    m = data["machine"]
    kind = "tiny" if data.get("tiny") else "quick" if data["quick"] else "full"
    md = ["# amfe: speed against error", "",
          f"Written by `python -m run.report.report{'' if kind == 'full' else ' --' + kind}` on "
          f"{m['date']} (commit {m['commit']}) in {_s(data['elapsed_seconds'])}. Machine: "
          f"{m['cpu']}, {m['cores']} cores, {m['memory_gib']} GiB; PETSc {m['petsc']}, "
          f"torch {m['torch']}, numpy {m['numpy']}, Python {m['python']}. Every number below "
          "comes from that run; run/report/report.py regenerates the page and its plots.", ""]
    for u in data.get("updated", []):
        md[-1:-1] = [f"Section(s) {', '.join(map(str, u['sections']))} rerun with `--sections` on "
                     f"{u['date']} (commit {u['commit']}) in {_s(u['seconds'])}; their numbers "
                     "come from that run.", ""]
    paths = []
    if "accuracy" in data:
        paths += section_accuracy(data["accuracy"], out, md)
    if "scaling" in data:
        p, fits, same = section_scaling(data["scaling"], out, md)
        paths += p
        data["scaling_fit"] = {str(k): v for k, v in fits.items()}
        data["rank_invariance"] = same
    if "rve" in data:
        from run.report.rve_write import section_rve
        paths += section_rve(data["rve"], out, md)
    if data.get("surrogate"):
        paths += section_surrogate(data["surrogate"], out, md)
        section_sizes(data.get("sizes"), md)
    elif "surrogate" in data:
        md += ["## 4. Surrogate against solver", "", "Not run: no held-out data set or trained "
               "model on this machine (run/train/train_surrogate.py makes both, docs/surrogate.md).", ""]
    if 5 in sections:
        section_paper(data, md)
    md += section_voxel(ROOT)
    text = "\n".join(md) + "\n"
    p_md = os.path.join(out, "report.md")
    atomic_write(p_md, lambda fh: fh.write(text.encode()))
    p_js = os.path.join(out, "report.json")
    atomic_write(p_js, lambda fh: fh.write(json.dumps(data, indent=1, default=float).encode()))
    return [p_md, p_js] + paths

"""Plot and markdown of the report's section 3 (run/report/report.py) from its measured rows.

:func:`section_rve` analyses the rows (:func:`report_rve.analyse`, pure) and
writes OUT/report_rve.png and the section's markdown; nothing here measures.
"""
import numpy as np

from run.report.rve import BC_LABEL, BCS, BEDS, FIT_TOL, MODULI, analyse, rel_change


def _pct(x):
    return "-" if x is None or np.isnan(x) else f"{100 * x:.2f} %"


def _mm(b):
    return "not at these sizes" if b is None else f"{b:g} mm"


def _plot(plt, rows, table, limits, h):
    """Ex and nu_xy against the base, the three conditions, one row of axes per bed kind."""
    kinds = list(limits)
    fig, axes = plt.subplots(len(kinds), 2, figsize=(11, 0.4 + 3.8 * len(kinds)), squeeze=False)
    for i, kind in enumerate(kinds):
        ent = [t for t in table if t["bed"] == kind]
        for j, (k, scale, unit) in enumerate((("Ex", 1e-9, "GPa"), ("nu_xy", 1.0, "-"))):
            ax = axes[i, j]
            for bc, color in zip(BCS, ("C3", "C0", "C2")):
                ax.plot([t["side_mm"] for t in ent], [scale * t["mean"][bc][k] for t in ent],
                        "o-", color=color, label=f"{BC_LABEL[bc]}, mean over seeds")
                rs = [r for r in rows if r["bed"] == kind and r["bc"] == bc]
                ax.plot([r["side_mm"] for r in rs], [scale * r["properties"][k] for r in rs], ".",
                        color=color, alpha=0.5)
            c = scale * limits[kind]["limit"][k]
            ax.axhline(c, color="k", ls="--", lw=0.8, label="common limit")
            ax.axhspan(0.99 * c, 1.01 * c, color="grey", alpha=0.25, label="limit +/- 1 %")
            ax.plot([], [], ".", color="grey", label="single seeds")
            ax.set_xlabel(f"base side [mm] (beds {h:g} mm high)")
            ax.set_ylabel(f"{k} [{unit}]")
            ax.set_title(f"{BEDS[kind]}: {k}")
            ax.grid(True, alpha=0.3)
    fig.tight_layout(rect=(0, 0.06 / len(kinds), 1, 1))
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", ncol=6, fontsize=8)
    return fig


def section_rve(rve, out, md):
    """Section 3's plot (OUT/report_rve.png) and markdown; returns the plot's path."""
    from run.report.figures import _plt, _s, _save
    kinds = analyse(rve)
    rows, table, limits = rve["rows"], rve["table"], rve["limits"]
    h = rve.get("height_mm", 0.3)
    path = _save(_plot(_plt(), rows, table, limits, h), f"{out}/report_rve.png")
    sc = rve["scan"]
    many = max(t["seeds"] for t in table)
    md += ["## 3. Representative volume", "",
           "KUBC (prescribed affine displacements on the boundary layer, the upper bound), "
           "SUBC (the matching uniform stress, the lower bound; both on the ordinary bed) and "
           "periodic (on the periodic bed of the same nominal size, seed and scan path, its box "
           "snapped to whole HCP periods: at most "
           f"{100 * max(t['snap'] for t in table):.1f} % off the base here) side by side "
           f"([docs/model.md](model.md), section 9). Beds {h:g} mm high, square bases of "
           f"growing side, {many} lattice seeds up to "
           f"{max(t['side_mm'] for t in table if t['seeds'] == many):g} mm; fully scanned, and "
           f"one scan pattern (tracks {1e3 * sc['track_width']:g} mm wide every "
           f"{1e3 * sc['hatch_spacing']:g} mm, first layer at {sc['angle']:g} deg, "
           f"{sc['layer_rotation']:g} deg rotation per layer). Change: the largest relative "
           "difference of the nine constants (means over seeds) from the common limit below. "
           f"Times on {rows[0]['ranks']} rank(s), the three conditions of one seed together.",
           "", "![representative volume](report_rve.png)", ""]
    for kind in kinds:
        lim = limits[kind]["limit"]
        more = [t["n_periodic"] / t["n_particles"] - 1 for t in table if t["bed"] == kind]
        md += [f"**{BEDS[kind].capitalize()}** (particles: the ordinary bed; the periodic bed, "
               f"whose lattice fills its box to the faces, holds {100 * min(more):.0f}-"
               f"{100 * max(more):.0f} % more)", "",
               "| base [mm] | seeds | particles | Ex KUBC [GPa] | Ex SUBC | Ex periodic "
               "| change KUBC | change SUBC | change periodic | seed spread | time per seed |",
               "|---|---|---|---|---|---|---|---|---|---|---|"]
        for t in (t for t in table if t["bed"] == kind):
            m = t["mean"]
            spread = np.nanmax(list(t["spread"].values())) if t["seeds"] > 1 else None
            md.append(f"| {t['side_mm']:g} | {t['seeds']} | {t['n_particles']:.0f} | "
                      + " | ".join(f"{m[bc]['Ex'] / 1e9:.1f}" for bc in BCS) + " | "
                      + " | ".join(_pct(rel_change(m[bc], lim)) for bc in BCS)
                      + f" | {_pct(spread)} | {_s(t['seconds'])} |")
        md.append("")
    md += _limit_text(rve, kinds) + _bracket_text(rve, kinds) + _convergence_text(rve, kinds)
    return [path]


def _ex_nu(c):
    return f"Ex {c['Ex'] / 1e9:.1f} GPa, Ez {c['Ez'] / 1e9:.1f} GPa, nu_xy {c['nu_xy']:.4f}"


def _limit_text(rve, kinds):
    """The common limit per bed kind: which one, why, the fits' quality; the summary table."""
    md = ["**The common limit.** Each condition's means are fitted by c(L) = c_inf + a / L per "
          "constant (a boundary layer of fixed thickness), once with one c_inf shared by the "
          "three conditions and once per condition. The shared c_inf is the common limit when "
          "that fit describes the means to 0.5 %; otherwise the conditions do not approach one "
          "limit at these sizes, and the limit is the periodic condition's own (periodic beds "
          "have no boundary, so theirs are the material's constants). Misfit: the largest "
          "relative difference of a fit from the means it was fitted to.", ""]
    for kind in kinds:
        lim, name = rve["limits"][kind], BEDS[kind].capitalize()
        sh, own = lim["shared"], lim["own"]
        if lim["source"] == "periodic largest":
            why = ("fewer than three bases, no fit" if sh is None else
                   f"no shared limit (the shared fit misses the means by {_pct(sh['misfit'])}), "
                   "and the periodic means do not follow c_inf + a / L either (misfit "
                   f"{_pct(own['periodic']['misfit'])})")
            md.append(f"- {name}: {why}. The common limit is the periodic mean on the largest "
                      f"bed ({_ex_nu(lim['limit'])}); where the periodic means still move, the "
                      "sizes below are relative to that bed, not to the infinite one.")
            continue
        fits = ", ".join(f"{BC_LABEL[bc]} {_pct(own[bc]['misfit'])}" for bc in BCS)
        sides = ", ".join(f"{b:g}" for b in sh["sides"])
        if lim["source"] == "shared":
            md.append(f"- {name}: the shared fit over {sides} mm misses the means by at most "
                      f"{_pct(sh['misfit'])} (own fits: {fits}); common limit "
                      f"{_ex_nu(lim['limit'])}.")
            continue
        off = {bc: rel_change(own[bc]["c_inf"], lim["limit"], MODULI) for bc in ("kubc", "subc")}
        big = max(t["side_mm"] for t in rve["table"] if t["bed"] == kind)
        last = next(t for t in rve["table"] if t["bed"] == kind and t["side_mm"] == big)
        md.append(f"- {name}: **no shared limit** - the shared fit over {sides} mm misses the "
                  f"means by up to {_pct(sh['misfit'])}, the conditions' own fits by {fits}. "
                  f"Common limit: the periodic fit, {_ex_nu(lim['limit'])} (the periodic "
                  f"{big:g} mm bed is {_pct(rel_change(last['mean']['periodic'], lim['limit']))}"
                  " from it). KUBC's own limit lies "
                  + " and SUBC's ".join(
                      f"{_pct(off[bc])} from it (Ex {_signed(own[bc], lim, 'Ex')}, Ez "
                      f"{_signed(own[bc], lim, 'Ez')})" for bc in ("kubc", "subc"))
                  + " (largest over the six moduli).")
    if any(rve["summary"][f"{k} {bc}"]["moduli_0.01"] is None for k in kinds
           for bc in ("kubc", "subc")):
        n = max(r["layers"] for r in rve["rows"] if r["bc"] == "kubc")
        md.append("- Why KUBC and SUBC keep an offset: the base grows, the height stays 0.3 mm. "
                  "Their top and bottom faces do not shrink with the base: KUBC prescribes the "
                  "particles there at every base, and both divide by the hull of the centres, "
                  "which spans one layer spacing less than the layers it holds, so in-plane "
                  f"moduli read stiffer by about n / (n - 1) = {n} / {n - 1} = {n / (n - 1):.3f} "
                  f"for these beds' n = {n} HCP layers ([docs/model.md](model.md), sections 5a "
                  "and 9). That offset fades only as the bed gets higher, which this study does "
                  "not vary.")
        md += [_face_text(rve, kind) for kind in kinds if _face_text(rve, kind)]
    md += ["", "Base from which the means stay within 5 % / 1 % of the common limit at every "
           "larger base measured (six moduli; all nine constants, with the Poisson ratios), "
           "and where each condition's own fit puts its moduli within 1 % of its own limit (only "
           f"where that fit describes the moduli to {100 * FIT_TOL:g} %):", "",
           "| bed | condition | within 5 %: moduli | all nine | within 1 %: moduli | all nine "
           "| own limit vs common (moduli) | 1 % of own limit (fit) |",
           "|---|---|---|---|---|---|---|---|"]
    for kind in kinds:
        for bc in BCS:
            s = rve["summary"][f"{kind} {bc}"]
            own = ("-" if s["own_misfit"] is None else
                   f"- (its fit misses by {_pct(s['own_misfit'])})" if s["own_offset"] is None
                   else _pct(s["own_offset"]))
            md.append(f"| {BEDS[kind]} | {BC_LABEL[bc]} | " + " | ".join(
                _mm(s[f"{k}_{tol}"]) for tol in (0.05, 0.01) for k in ("moduli", "all"))
                + f" | {own} | "
                + ("-" if s["own_1"] is None else f"about {s['own_1']:.2g} mm") + " |")
    return md + [""]


def _face_text(rve, kind, above=0.2):
    """A line when KUBC's Ex stays far above the limit on ``kind`` beds at every base."""
    ent = sorted((t for t in rve["table"] if t["bed"] == kind), key=lambda t: t["side_mm"])
    c = rve["limits"][kind]["limit"]["Ex"]
    r0, r1 = (ent[i]["mean"]["kubc"]["Ex"] / c for i in (0, -1))
    b0, b1 = ent[0]["side_mm"], ent[-1]["side_mm"]
    kept = (r1 - 1) / (r0 - 1) if r0 > 1 else 0.0
    if r1 < 1 + above or kept < 2 * b0 / b1:     # far above, and shrinking far slower than 1/L
        return None
    return (f"- {BEDS[kind].capitalize()}: KUBC's Ex is {r1:.2f}x the limit at {b1:g} mm "
            f"({r0:.2f}x at {b0:g} mm). Far beyond n / (n - 1), this excess keeps "
            f"{100 * kept:.0f} % of itself from {b0:g} to {b1:g} mm, where a layer on the side "
            f"faces would keep {100 * b0 / b1:.0f} % (1/L): it sits on the faces that do not "
            "grow. KUBC moves every particle of the top and bottom layers with the affine field "
            "at any base, so the tracks there act as if joined across the gaps the scan path "
            "leaves.")


def _signed(fit, lim, k):
    return f"{100 * (fit['c_inf'][k] / lim['limit'][k] - 1):+.1f} %"


def _bracket_text(rve, kinds):
    """SUBC <= periodic <= KUBC, counted over (base, seed, constant), moduli and ratios."""
    md = ["**The bracket.** Counted over every base, seed and constant (periodic on its own "
          "bed, so the order is a measurement, not a theorem):", ""]
    for kind in kinds:
        m, r = rve["bracket"]["moduli"][kind], rve["bracket"]["ratios"][kind]
        if not m["cases"]:
            continue
        line = (f"- {BEDS[kind]}: moduli - SUBC <= KUBC in {m['subc_kubc']} of {m['cases']}; "
                f"SUBC <= periodic <= KUBC in {m['held']} of {m['cases']}")
        if m["below_subc"]:
            line += (f"; periodic below both in {m['below_subc']} (by up to "
                     f"{_pct(m['worst_below'])})")
        if m["above_kubc"]:
            line += f"; above both in {m['above_kubc']} (by up to {_pct(m['worst_above'])})"
        md.append(line + f". Poisson ratios - SUBC <= KUBC in {r['subc_kubc']} of {r['cases']}, "
                  f"periodic between them in {r['held']} of {r['cases']}.")
    md += ["", "The energy ordering e : C_subc : e <= e : C_kubc : e makes SUBC's moduli the "
           "lower ones on the same bed; it says nothing about Poisson ratios, which are ratios "
           "of compliances and fall on either side. Where periodic lies below SUBC, the finite "
           "bed's hull volume (above) lifts both finite conditions over the material's value.",
           ""]
    return md


def _convergence_text(rve, kinds):
    """Issue 14's convergence line (periodic, 0.6 -> 1.2 mm) and the cost of the conditions."""
    md = []
    for kind in kinds:
        c = rve["convergence"][kind]
        if c is None:
            md.append(f"- {BEDS[kind].capitalize()} periodic beds: convergence from 0.6 to 1.2 mm "
                      "not measured (this run has no beds of both sizes).")
            continue
        ok = "within" if c["mean"] < 0.02 else "**not** within"
        md.append(f"- {BEDS[kind].capitalize()} periodic beds: the moduli change by "
                  f"{_pct(c['mean'])} (means over seeds; worst single seed "
                  f"{_pct(c['worst_seed'])}) from a 0.6 mm to a 1.2 mm base, {ok} 2 %.")
    conv = rve["convergence"]
    if "scan" in kinds:
        md.append("- A scan path does not tile the periodic box: the tracks are laid in the box "
                  "as on an ordinary bed and cut at its faces, so the periodic bed repeats a "
                  "seam, and a small box holds only a few hatch spacings (0.6 mm: about "
                  f"{0.6e-3 / rve['scan']['hatch_spacing']:.0f}). Both effects fade as the base "
                  "grows, and fully scanned periodic beds have neither"
                  + (": hence the two convergence figures above." if conv.get("full") and
                     conv.get("scan") and conv["full"]["mean"] < 0.02 <= conv["scan"]["mean"]
                     else "."))
    for kind in kinds:
        ent = sorted((t for t in rve["table"] if t["bed"] == kind), key=lambda t: t["side_mm"])
        its = [f"{BC_LABEL[bc]} {ent[0]['iterations'][bc]:.0f} -> {ent[-1]['iterations'][bc]:.0f}"
               for bc in BCS]
        md.append(f"- Cost, {BEDS[kind]}: CG iterations per load case from {ent[0]['side_mm']:g} "
                  f"to {ent[-1]['side_mm']:g} mm: {', '.join(its)}.")
    sub = {k: [t["iterations"]["subc"] for t in sorted(rve["table"], key=lambda t: t["side_mm"])
               if t["bed"] == k] for k in kinds}
    if any(v[-1] > 1.5 * v[0] for v in sub.values()):
        md.append("- SUBC holds one particle only, no boundary, and its iterations grow with "
                  "the bed; it takes most of the time of the larger beds.")
    return ["**Convergence.**", ""] + md + [""]

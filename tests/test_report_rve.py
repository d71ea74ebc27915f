"""Section 3 of the report (run/report/rve.py): the analysis of its rows, on synthetic rows
whose limits, offsets and orderings are known."""
import os

import pytest

from run.report import rve as R


def curve(c_inf, a, side):
    """Constants c_inf + a / side for every constant (c_inf, a: numbers or {constant: number})."""
    def get(v, k):
        return v[k] if isinstance(v, dict) else v
    return {k: get(c_inf, k) + get(a, k) / side for k in R.CONSTANTS}


def rows_from(law, sides=(0.3, 0.6, 0.9, 1.2, 1.8), seeds=(0,), kinds=("full",)):
    """Rows as the worker writes them; ``law(kind, bc, side, seed)`` gives the constants."""
    return [{"bed": kind, "side_mm": b, "seed": s, "bc": bc, "ranks": 2,
             "n_particles": int(1000 * b * b) + (100 if bc == "periodic" else 0), "n_bonds": 1,
             "properties": law(kind, bc, b, s), "box_mm": [b * 1.01, b], "layers": 15,
             "seconds": 1.0 + b, "iterations": 10.0 * b}
            for kind in kinds for b in sides for s in seeds for bc in R.BCS]


def entries(rows, kind="full"):
    return [t for t in R.rve_table(rows) if t["bed"] == kind]


def test_plan_seeds_and_budget():
    for quick, tiny in ((False, False), (True, False), (False, True)):
        plan = R.rve_plan(quick, tiny)
        full = sorted((b, s) for k, b, s in plan if k == "full")
        scan = sorted((b, s) for k, b, s in plan if k == "scan")
        assert set(scan) <= set(full)                    # same bases and seeds where both
        seeds = {b: sum(1 for bb, _ in full if bb == b) for b, _ in full}
        assert seeds[min(seeds)] >= seeds[max(seeds)]    # more seeds where the bed is small
    full = R.rve_plan(False)
    assert sum(1 for k, b, _ in full if k == "full" and b == 0.3) == 3
    assert {0.6, 1.2} <= {b for _, b, _ in R.rve_plan(True)}   # the convergence pair
    # the estimate adds the beds' costs; the full plan fits the ~20 min budget
    one = R.plan_seconds([("full", 0.6, 0)])
    assert one == pytest.approx(R.SECONDS_AT_06["full"])
    assert R.plan_seconds([("full", 1.2, 0)]) == pytest.approx(one * 2 ** R.COST_EXPONENT)
    assert R.plan_seconds(full) <= 20 * 60


def test_table_means_spread_and_snap():
    def law(kind, bc, b, s):   # seeds 0, 1: 1.00 and 1.02
        return curve(1.0 + 0.02 * s, 0.0, b)
    t = entries(rows_from(law, sides=(0.6,), seeds=(0, 1)))[0]
    assert t["seeds"] == 2 and t["mean"]["subc"]["Ex"] == pytest.approx(1.01)
    assert t["spread"]["kubc"] == pytest.approx(0.01 / 1.01)     # population std / mean
    assert t["n_particles"] == 360 and t["n_periodic"] == 460
    assert t["snap"] == pytest.approx(0.01) and t["seconds"] == pytest.approx(3 * 1.6)   # per seed


def test_shared_limit_recovered_when_all_conditions_approach_it():
    a = {"kubc": 0.2, "subc": -0.3, "periodic": 0.01}
    rows = rows_from(lambda kind, bc, b, s: curve(2.0, a[bc], b))
    lim = R.common_limit(entries(rows))
    assert lim["source"] == "shared" and lim["shared"]["misfit"] < 1e-12
    assert lim["limit"]["Ex"] == pytest.approx(2.0)
    assert lim["shared"]["a"]["subc"]["G_xy"] == pytest.approx(-0.3)
    assert lim["shared"]["sides"] == [0.6, 0.9, 1.2, 1.8]        # bases >= 0.6 mm
    # a / (tol c_inf): KUBC within 1 % of its own limit from 0.2 / (0.01 * 2) = 10 mm
    assert R.fit_within(lim["own"]["kubc"], "kubc", 0.01) == pytest.approx(10.0)


def test_offset_condition_rejects_the_shared_fit():
    """KUBC converging 7 % above the others: no shared limit, the periodic fit is the limit."""
    c = {"kubc": 2.14, "subc": 2.0, "periodic": 2.0}
    a = {"kubc": 0.1, "subc": -0.1, "periodic": 0.0}
    rows = rows_from(lambda kind, bc, b, s: curve(c[bc], a[bc], b))
    ent = entries(rows)
    lim = R.common_limit(ent)
    assert lim["source"] == "periodic fit" and lim["shared"]["misfit"] > R.SHARED_TOL
    assert lim["limit"]["Ez"] == pytest.approx(2.0)
    assert lim["own"]["kubc"]["c_inf"]["Ex"] == pytest.approx(2.14)
    assert R.within_from(ent, "kubc", lim["limit"], 0.05) is None   # 7 % off at any base
    # SUBC: 2 - 0.1/L is within 5 % (0.1 / L < 0.1) from L > 1 on, within 1 % never here
    assert R.within_from(ent, "subc", lim["limit"], 0.05) == 1.2
    assert R.within_from(ent, "subc", lim["limit"], 0.01) is None
    assert R.within_from(ent, "periodic", lim["limit"], 0.01) == 0.3


def test_few_bases_fall_back_to_the_largest_periodic_bed():
    rows = rows_from(lambda kind, bc, b, s: curve(2.0 + (bc == "periodic"), 0.1, b),
                     sides=(0.3, 0.6))
    lim = R.common_limit(entries(rows))
    assert lim["source"] == "periodic largest" and lim["shared"] is None
    assert lim["limit"]["Ex"] == pytest.approx(3.0 + 0.1 / 0.6)


def test_within_from_needs_every_larger_base():
    """A base inside the band counts only if no larger base leaves it again."""
    vals = {0.3: 1.3, 0.6: 1.004, 0.9: 1.02, 1.2: 1.005, 1.8: 1.0}
    ent = entries(rows_from(lambda kind, bc, b, s: curve(vals[b], 0.0, b)))
    lim = dict.fromkeys(R.CONSTANTS, 1.0)
    assert R.within_from(ent, "kubc", lim, 0.01) == 1.2
    assert R.within_from(ent, "kubc", lim, 0.05) == 0.6
    assert R.within_from(ent, "kubc", lim, 0.5) == 0.3


def test_bracket_counts_and_excursions():
    def law(kind, bc, b, s):
        p = dict.fromkeys(R.CONSTANTS, {"kubc": 3.0, "subc": 1.0, "periodic": 2.0}[bc])
        if bc == "periodic" and b == 0.6:
            p["Ex"] = 0.9                      # 10 % below SUBC
            p["nu_xy"] = 4.5                   # 50 % above KUBC
        return p
    br = R.bracket(rows_from(law, sides=(0.3, 0.6), seeds=(0, 1)), R.MODULI)["full"]
    assert br["cases"] == 2 * 2 * 6 and br["subc_kubc"] == 24
    assert br["held"] == 22 and br["below_subc"] == 2 and br["above_kubc"] == 0
    assert br["worst_below"] == pytest.approx(1.0 / 0.9 - 1)
    ratios = R.bracket(rows_from(law, sides=(0.3, 0.6)), R.RATIOS)["full"]
    assert ratios["above_kubc"] == 1 and ratios["worst_above"] == pytest.approx(0.5)


def test_convergence_of_periodic_beds():
    """Largest modulus change from 0.6 to 1.2 mm; the Poisson ratios do not count."""
    def law(kind, bc, b, s):
        p = curve(1.0, 0.0, b)
        if bc == "periodic" and b == 1.2:
            p["G_xz"] = 1.0 + 0.01 * (s + 1)   # seed 0: +1 %, seed 1: +2 %
            p["nu_xy"] = 5.0
        return p
    c = R.convergence(rows_from(law, sides=(0.6, 1.2), seeds=(0, 1)), "full")
    assert c["mean"] == pytest.approx(0.015) and c["worst_seed"] == pytest.approx(0.02)
    assert c["seeds"] == [0, 1]
    assert R.convergence(rows_from(law, sides=(0.3, 0.6)), "full") is None


def test_section_markdown_and_plot(tmp_path):
    """The writer's tables carry the rows' numbers; one PNG; JSON-ready analysis."""
    import json

    from run.report.rve_write import section_rve
    c = {"kubc": 2.14e11, "subc": 2.0e11, "periodic": 2.0e11}
    rows = rows_from(lambda kind, bc, b, s: curve(c[bc], 1e9 * (bc == "kubc"), b),
                     seeds=(0, 1), kinds=("full", "scan"))
    rve = {"rows": rows, "scan": R.RVE_SCAN, "height_mm": 0.3}
    md = []
    paths = section_rve(rve, str(tmp_path), md)
    assert paths == [f"{tmp_path}/report_rve.png"] and os.path.getsize(paths[0]) > 10_000
    text = "\n".join(md)
    # 1.8 mm row: KUBC 214 + 1/1.8 GPa, SUBC and periodic 200 GPa, 7.0 % from the limit
    assert "| 1.8 | 2 | 3240 | 214.6 | 200.0 | 200.0 | 7.28 % | 0.00 % | 0.00 % |" in text
    assert text.count("| fully scanned | ") == 3 and text.count("| scan pattern | ") == 3
    assert "**no shared limit**" in text and "15 / 14" in text
    json.dumps(rve)                                    # report.json can hold it

"""Section 3 of the report (run/report/report.py): the representative volume under three conditions.

KUBC (the upper bound) and SUBC (the lower bound) are solved on the ordinary
bed of each nominal size and seed; periodic on the periodic bed of the same
nominal size, seed and scan pattern (its box snapped to whole HCP periods,
docs/model.md section 9). Two bed kinds: fully scanned, and one scan pattern
(:data:`RVE_SCAN`). All beds are 0.3 mm high; only the square base grows.

Measuring (:func:`worker`, under mpirun) gives one row per bed kind, base,
seed and condition; the rest is pure numpy on those rows: the mean over
seeds per base (:func:`rve_table`), the common limit and its fit
(:func:`common_limit`), the base from which a condition stays within a
tolerance (:func:`within_from`), the bracket (:func:`bracket`) and the
periodic convergence (:func:`convergence`). Moduli in Pa, ratios and
changes dimensionless, bases in mm, times in wall-clock seconds.
"""
import time

import numpy as np

from amfe.vocab import CONSTANT_NAMES as CONSTANTS

BCS = ("kubc", "subc", "periodic")
BC_LABEL = {"kubc": "KUBC", "subc": "SUBC", "periodic": "periodic"}
BEDS = {"full": "fully scanned", "scan": "scan pattern"}
MODULI = ("Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy")
RATIOS = ("nu_yz", "nu_xz", "nu_xy")
HEIGHT_MM = 0.3
RVE_SCAN = dict(track_width=0.1e-3, hatch_spacing=0.14e-3, angle=30.0, layer_rotation=90.0,
                offset=0.0)
#: wall seconds of the three conditions on one 0.6 mm bed (generation included), 2 ranks of
#: the report's 2-core machine as measured on 2026-12-01 with other jobs running (load 5-8;
#: the same beds took up to 1.5x longer an hour later)
SECONDS_AT_06 = {"full": 28.0, "scan": 31.0}
#: t ~ base^COST_EXPONENT: particles ~ base^2, and SUBC's iterations grow with the base
#: (measured 0.6 -> 1.2 -> 1.8 mm: 28, 107-114, 306 s on fully scanned beds)
COST_EXPONENT = 2.2


def rve_plan(quick, tiny=False):
    """[(bed kind, base mm, seed)] of section 3: three seeds up to 0.6 mm, one above.

    The three conditions share every bed's base and seed. Scan-pattern beds stop
    at 1.2 mm in the full plan (SUBC's iterations grow fastest on them; 1.8 mm
    would add about 6 min), fully scanned ones go on to 1.8 mm. --quick keeps
    0.6 and 1.2 mm (the convergence check's pair); --tiny two small beds per kind.
    """
    if tiny:
        sizes, small, seeds = {"full": (0.2, 0.3), "scan": (0.2, 0.3)}, 0.3, (0,)
    elif quick:
        sizes, small, seeds = {"full": (0.3, 0.6, 1.2), "scan": (0.3, 0.6, 1.2)}, 0.3, (0, 1)
    else:
        sizes, small, seeds = ({"full": (0.3, 0.6, 0.9, 1.2, 1.8), "scan": (0.3, 0.6, 0.9, 1.2)},
                               0.6, (0, 1, 2))
    return [(kind, b, s) for kind in BEDS for b in sizes[kind]
            for s in (seeds if b <= small + 1e-9 else seeds[:1])]


def plan_seconds(plan):
    """Estimated wall seconds of ``plan`` on 2 ranks (:data:`SECONDS_AT_06`,
    :data:`COST_EXPONENT`)."""
    return float(sum(SECONDS_AT_06[k] * (b / 0.6) ** COST_EXPONENT for k, b, _ in plan))


def worker(items, comm, log):
    """Rows of every (bed kind, base, seed) item: KUBC and SUBC on the ordinary bed, periodic
    on the periodic one. Runs on every rank of ``comm``; ``log`` prints on rank 0.

    Row: bed, side_mm, seed, bc, ranks, n_particles, n_bonds, properties (the nine
    constants, SI), box_mm (the bed's lateral sides: the requested base, or the
    periodic bed's snapped box), layers (HCP layers of the bed: the z extent of
    the centres over the layer spacing 2 r0 sqrt(2/3), plus one), seconds
    (generation + homogenization, wall), iterations (mean over the six cases).
    """
    from amfe.model.bed import generate_bed
    from amfe.model.scanpath import ScanPath
    from amfe.solvers.driver import homogenize_bed
    from amfe.model.options import SolveOptions
    rows = []
    for kind, side, seed in items:
        scan = None if kind == "full" else ScanPath(**RVE_SCAN)
        size = (side * 1e-3, side * 1e-3, HEIGHT_MM * 1e-3)
        for periodic, bcs in ((False, ("kubc", "subc")), (True, ("periodic",))):
            comm.barrier()
            t0 = time.perf_counter()
            bed = generate_bed(size, seed=seed, scan=scan, periodic=periodic)
            t_gen = time.perf_counter() - t0
            box = bed.attrs.get("periodic")
            z = bed.centers[:, 2]
            layers = int(round((z.max() - z.min()) / (2 * bed.attrs["r0"] * (2 / 3) ** 0.5))) + 1
            for bc in bcs:
                t0 = time.perf_counter()
                r = homogenize_bed(bed, SolveOptions(solver="gamg", bc=bc,
                                                     material=bed.material()), comm).to_dict()
                row = {"bed": kind, "side_mm": side, "seed": seed, "bc": bc,
                       "ranks": comm.getSize(), "n_particles": r["n_particles"],
                       "n_bonds": r["n_bonds"], "properties": r["properties"],
                       "box_mm": [1e3 * v for v in (box or size)[:2]], "layers": layers,
                       "seconds": t_gen + time.perf_counter() - t0,
                       "iterations": float(np.mean(r["solver"]["iterations"]))}
                t_gen = 0.0
                rows.append(row)
                log(f"    rve {kind} {side:4.2f} mm seed {seed} {bc:8s}: {row['n_particles']:7d} "
                    f"particles, {row['seconds']:6.2f} s, {row['iterations']:.1f} its, "
                    f"Ex {r['properties']['Ex'] / 1e9:6.1f} GPa")
    return rows


# ------------------------------------------------------------ analysis (pure)

def rel_change(props, ref, keys=CONSTANTS):
    """max over ``keys`` of |props[k] / ref[k] - 1|."""
    return float(max(abs(props[k] / ref[k] - 1.0) for k in keys))


def rve_table(rows):
    """Per (bed kind, base): the seeds' mean constants of each condition, their spread, cost.

    Entry: bed, side_mm, seeds, n_particles and n_periodic (means: the ordinary
    and the periodic bed), mean {bc: {constant: value}}, spread {bc: largest
    relative standard deviation over the nine constants, nan for one seed},
    seconds (mean over seeds of the three conditions together), iterations
    {bc: mean CG iterations per case}, snap (largest |box / base - 1| of the
    periodic beds).
    """
    table = []
    for kind in BEDS:
        for side in sorted({r["side_mm"] for r in rows if r["bed"] == kind}):
            rs = [r for r in rows if r["bed"] == kind and r["side_mm"] == side]
            seeds = sorted({r["seed"] for r in rs})
            by = {bc: [r for r in rs if r["bc"] == bc] for bc in BCS}
            mean = {bc: {k: float(np.mean([r["properties"][k] for r in by[bc]])) for k in CONSTANTS}
                    for bc in BCS if by[bc]}
            spread = {bc: max(float(np.std([r["properties"][k] for r in by[bc]]) / abs(mean[bc][k]))
                              for k in CONSTANTS) if len(by[bc]) > 1 else float("nan")
                      for bc in mean}
            table.append({
                "bed": kind, "side_mm": side, "seeds": len(seeds), "mean": mean, "spread": spread,
                "n_particles": float(np.mean([r["n_particles"] for r in by["kubc"] or by["subc"]])),
                "n_periodic": float(np.mean([r["n_particles"] for r in by["periodic"]])),
                "seconds": float(sum(r["seconds"] for r in rs) / len(seeds)),
                "iterations": {bc: float(np.mean([r["iterations"] for r in by[bc]]))
                               for bc in mean},
                "snap": max((abs(b / side - 1.0) for r in by["periodic"] for b in r["box_mm"]),
                            default=0.0)})
    return table


def fit_sides(entries, min_side=0.6):
    """The bases [mm] a 1/L fit uses: those >= ``min_side``, or the three largest if fewer."""
    sides = sorted(t["side_mm"] for t in entries)
    use = [b for b in sides if b >= min_side - 1e-9]
    return use if len(use) >= 3 else sides[-3:]


def fit_limits(entries, bcs, min_side=0.6):
    """Least squares c(L) = c_inf + a_bc / L per constant, ONE c_inf shared by ``bcs``.

    entries: :func:`rve_table` rows of one bed kind. With a single condition
    this is that condition's own limit. Returns {c_inf {k}, a {bc: {k}}, misfit
    (largest |fit / mean - 1| over the bases, conditions and constants),
    misfit_moduli (the same over the six moduli), sides} or None with fewer
    than three bases (or a condition missing).
    """
    use = [t for t in entries if t["side_mm"] in fit_sides(entries, min_side)]
    if len(use) < 3 or not all(bc in t["mean"] for t in use for bc in bcs):
        return None
    inv = np.array([1.0 / t["side_mm"] for t in use])
    A = np.zeros((len(bcs) * len(use), 1 + len(bcs)))       # [c_inf, a_bc...] per block
    A[:, 0] = 1.0
    for j in range(len(bcs)):
        A[j * len(use):(j + 1) * len(use), 1 + j] = inv
    out = {"c_inf": {}, "a": {bc: {} for bc in bcs}, "misfit": 0.0, "misfit_moduli": 0.0,
           "sides": [t["side_mm"] for t in use]}
    for k in CONSTANTS:
        y = np.concatenate([[t["mean"][bc][k] for t in use] for bc in bcs])
        coef = np.linalg.lstsq(A, y, rcond=None)[0]
        out["c_inf"][k] = float(coef[0])
        for j, bc in enumerate(bcs):
            out["a"][bc][k] = float(coef[1 + j])
        miss = float(np.max(np.abs(A @ coef / y - 1.0)))
        out["misfit"] = max(out["misfit"], miss)
        if k in MODULI:
            out["misfit_moduli"] = max(out["misfit_moduli"], miss)
    return out


#: a shared-limit fit that misses the means by more than this is rejected
SHARED_TOL = 0.005
#: a condition's own 1/L fit that misses its means by more than this is not extrapolated
FIT_TOL = 0.01


def common_limit(entries, min_side=0.6):
    """The limit all conditions are measured against, for one bed kind.

    The shared fit (:func:`fit_limits` over the three conditions) when it
    describes the means to :data:`SHARED_TOL`; otherwise the conditions do not
    approach one limit at these sizes, and the material's own constants are
    taken from the periodic condition (no boundary layer): its own 1/L fit
    when that describes its means to :data:`FIT_TOL`, else (no fit, or a bad
    one) its mean on the largest base.
    Returns {limit {k}, source, shared, own {bc: fit or None}}.
    """
    shared = fit_limits(entries, BCS, min_side)
    own = {bc: fit_limits(entries, (bc,), min_side) for bc in BCS}
    if shared is not None and shared["misfit"] <= SHARED_TOL:
        limit, source = shared["c_inf"], "shared"
    elif own["periodic"] is not None and own["periodic"]["misfit"] <= FIT_TOL:
        limit, source = own["periodic"]["c_inf"], "periodic fit"
    else:
        limit, source = dict(max(entries, key=lambda t: t["side_mm"])["mean"]["periodic"]), \
            "periodic largest"
    return {"limit": limit, "source": source, "shared": shared, "own": own}


def within_from(entries, bc, limit, tol, keys=CONSTANTS):
    """Smallest measured base [mm] from which ``bc``'s means stay within ``tol`` of ``limit``
    at every larger measured base (``keys``); None if the largest base is not within."""
    best = None
    for t in sorted(entries, key=lambda t: -t["side_mm"]):
        if rel_change(t["mean"][bc], limit, keys) >= tol:
            break
        best = t["side_mm"]
    return best


def fit_within(fit, bc, tol, keys=CONSTANTS):
    """Base [mm] from which ``fit``'s curve for ``bc`` is within ``tol`` of its own c_inf."""
    return float(max(abs(fit["a"][bc][k]) / (tol * abs(fit["c_inf"][k])) for k in keys))


def bracket(rows, keys):
    """Is SUBC <= periodic <= KUBC per (bed kind, base, seed) and constant in ``keys``?

    Returns {cases, subc_kubc (SUBC <= KUBC holds: same bed), held (all three
    in order), below_subc, above_kubc (periodic outside), worst_below,
    worst_above (largest relative excursion of periodic outside the pair, 0
    if none)}, per bed kind.
    """
    out = {}
    for kind in BEDS:
        by = {(r["side_mm"], r["seed"], r["bc"]): r["properties"] for r in rows if r["bed"] == kind}
        n = dict(cases=0, subc_kubc=0, held=0, below_subc=0, above_kubc=0, worst_below=0.0,
                 worst_above=0.0)
        for (side, seed, bc) in by:
            if bc != "kubc" or (side, seed, "subc") not in by or (side, seed, "periodic") not in by:
                continue
            hi, lo, p = by[(side, seed, "kubc")], by[(side, seed, "subc")], \
                by[(side, seed, "periodic")]
            for k in keys:
                n["cases"] += 1
                n["subc_kubc"] += lo[k] <= hi[k]
                below, above = p[k] < min(lo[k], hi[k]), p[k] > max(lo[k], hi[k])
                n["held"] += lo[k] <= p[k] <= hi[k]
                n["below_subc"] += below
                n["above_kubc"] += above
                if below:
                    n["worst_below"] = max(n["worst_below"], min(lo[k], hi[k]) / p[k] - 1.0)
                if above:
                    n["worst_above"] = max(n["worst_above"], p[k] / max(lo[k], hi[k]) - 1.0)
        out[kind] = n
    return out


def convergence(rows, kind, small=0.6, large=1.2, bc="periodic", keys=MODULI):
    """Largest relative change of ``keys`` from base ``small`` to ``large`` (``bc`` beds).

    Returns {mean: of the seeds' means, worst_seed: over the seeds measured at
    both bases, seeds: those seeds} or None when a base is missing.
    """
    def props(side):
        return {r["seed"]: r["properties"] for r in rows
                if r["bed"] == kind and r["bc"] == bc and abs(r["side_mm"] - side) < 1e-9}
    a, b = props(small), props(large)
    if not a or not b:
        return None
    mean = [{k: float(np.mean([p[k] for p in d.values()])) for k in keys} for d in (a, b)]
    both = sorted(set(a) & set(b))
    return {"mean": rel_change(mean[1], mean[0], keys), "seeds": both,
            "worst_seed": max((rel_change(b[s], a[s], keys) for s in both), default=float("nan"))}


def analyse(rve):
    """Add table, limits, summary, bracket and convergence to ``rve`` (from its rows)."""
    rows = rve["rows"]
    rve["table"] = table = rve_table(rows)
    kinds = [k for k in BEDS if any(t["bed"] == k for t in table)]
    rve["limits"] = {k: common_limit([t for t in table if t["bed"] == k]) for k in kinds}
    rve["summary"] = {}
    for kind in kinds:
        ent = [t for t in table if t["bed"] == kind]
        lim = rve["limits"][kind]
        for bc in BCS:
            own = lim["own"][bc]
            good = own is not None and own["misfit_moduli"] <= FIT_TOL
            rve["summary"][f"{kind} {bc}"] = {
                **{f"{keys}_{tol}": within_from(ent, bc, lim["limit"], tol,
                                                MODULI if keys == "moduli" else CONSTANTS)
                   for keys in ("moduli", "all") for tol in (0.05, 0.01)},
                "own_misfit": own and own["misfit_moduli"],
                "own_offset": rel_change(own["c_inf"], lim["limit"], MODULI) if good else None,
                "own_1": fit_within(own, bc, 0.01, MODULI) if good else None}
    rve["bracket"] = {"moduli": bracket(rows, MODULI), "ratios": bracket(rows, RATIOS)}
    rve["convergence"] = {k: convergence(rows, k) for k in kinds}
    return kinds

"""Speed against error: regenerate docs/report.md and its plots from scratch (issue 7).

    source run/env.sh
    .venv/bin/python -m run.report.report            # full report, about 10-15 min on 2 cores
    .venv/bin/python -m run.report.report --quick    # the same sections on smaller beds, < 5 min

Sections (every number is measured by this run, on this machine):

1. solver accuracy against cost on a realistic bed: CG + GAMG / hypre
   BoomerAMG / Jacobi at rtol 1e-2 ... 1e-10, PETSc Cholesky (MUMPS; CHOLMOD
   where PETSc has it) and scipy SuperLU, max relative error of the nine
   constants against CG + GAMG at rtol 1e-12; Pareto plot and the
   recommended default;
2. scaling of fully scanned 0.3 mm high beds from about 1 000 particles to
   the paper's full bed (3 x 3 x 0.3 mm): time per phase and iterations,
   fitted exponent, cost of a solve in fine-level matrix-vector products,
   1 and ``--ranks`` ranks (each run is an ``mpirun`` of this script);
3. representative volume: KUBC, SUBC and periodic side by side on fully
   scanned beds and one scan pattern against the base size, the common
   limit, the base within 1 % and 5 % of it, the bracket, the convergence of
   periodic beds (run/report/rve.py, run/report/rve_write.py);
4. surrogate against solver on the held-out data set (``--test``) with the
   networks found in ``--models`` (run/train/train_surrogate.py's checkpoints) or
   the shipped model; skipped, and said so, when neither is there;
5. against the paper's figures.

Writes OUT/report.md, OUT/report_*.png and OUT/report.json (all numbers),
each atomically. ``--sections 4,5`` reruns only those sections and keeps the
others' numbers from OUT/report.json (the page names what was rerun, when,
at which commit). ``--tiny`` shrinks everything further (for the test suite).
"""
import argparse
import json
import os
import sys
import tempfile
import time

from run.common import ROOT, parser  # noqa: E402

from run.report import measure as M  # noqa: E402
from run.report import surrogate_cost as S  # noqa: E402
from run.report import rve as R  # noqa: E402

def parse(argv):
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="smaller beds: under 5 minutes")
    ap.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(ROOT, "docs"), help="output folder (docs/)")
    ap.add_argument("--ranks", type=int, default=2, help="the second rank count of section 2")
    ap.add_argument("--sections", default="1,2,3,4,5", help="comma list of sections to run")
    ap.add_argument("--test", default="/work/data/small_test.h5",
                    help="held-out data set of section 4")
    ap.add_argument("--size-test", action="append", default=[], metavar="SCALE=PATH",
                    help="section 4 by bed size: a scale's held-out data set (repeat; default: "
                         "run/report/sizes.py's that exist)")
    ap.add_argument("--models", default="/work/data/surrogate",
                    help="folder of run/train/train_surrogate.py's checkpoints (section 4)")
    ap.add_argument("--rewrite", action="store_true",
                    help="only redraw OUT/report.md and the plots from OUT/report.json")
    ap.add_argument("--worker", choices=("scaling", "rve"), help=argparse.SUPPRESS)
    ap.add_argument("--items", help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def previous_run(out, sections, quick, tiny):
    """The report.json a partial run (--sections) updates, or None for a whole run.

    A run of some sections keeps the others' numbers from the last run of the
    same kind (full, quick or tiny) in ``out``; with none there, the page has
    only the sections run.
    """
    path = os.path.join(out, "report.json")
    if sections == {1, 2, 3, 4, 5} or not os.path.exists(path):
        return None
    with open(path) as fh:
        old = json.load(fh)
    return old if (old.get("quick"), old.get("tiny")) == (quick, tiny) else None


def main(argv=None):
    args = parse(argv)
    if args.worker:
        items = json.loads(args.items)
        M.worker(args.worker, [tuple(i) if isinstance(i, list) else i for i in items],
                 args.worker_out)
        return 0
    if args.rewrite:
        from run.report.write import write_report
        with open(os.path.join(args.out, "report.json")) as fh:
            data = json.load(fh)
        write_report(data, args.out, {int(s) for s in args.sections.split(",")})
        return 0
    quick = args.quick or args.tiny
    try:
        sections = {int(s) for s in args.sections.split(",")}
    except ValueError:
        sections = set()
    if not sections or not sections <= {1, 2, 3, 4, 5}:
        print(f"report.py: --sections must be a comma list of 1-5, got {args.sections!r}",
              file=sys.stderr)
        return 2
    try:
        os.makedirs(args.out, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=args.out)
        probe.close()
    except OSError as exc:
        print(f"report.py: cannot write the report to {args.out}: {exc}", file=sys.stderr)
        return 2
    t_start = time.perf_counter()

    def log(msg):
        print(msg, flush=True)

    data = {"machine": M.machine(), "quick": quick, "tiny": args.tiny}
    base = previous_run(args.out, sections, quick, args.tiny)
    log(f"amfe report ({'tiny' if args.tiny else 'quick' if quick else 'full'}) on "
        f"{data['machine']['cores']} cores, PETSc {data['machine']['petsc']}")
    with tempfile.TemporaryDirectory() as tmp:
        if 1 in sections:
            log("[1] solver accuracy against cost")
            bed, desc = M.pareto_bed(quick)
            rtols = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10] if quick else [10.0**-k for k in range(2, 11)]
            acc = M.accuracy_vs_cost(bed, rtols, log)
            acc["bed"] = desc
            acc["recommended"] = M.recommend(acc)
            growth = [0.18, 0.35] if args.tiny else [0.35, 0.7] if quick else [0.35, 0.7, 1.0, 1.4]
            acc["growth"] = M.direct_vs_iterative(growth, log)
            data["accuracy"] = acc
        if 2 in sections:
            log("[2] scaling")
            sizes = M.scaling_sizes(quick, args.tiny)
            rows = []
            for ranks in sorted({1, args.ranks}):
                rows += M.run_worker("scaling", sizes, ranks, os.path.join(tmp, f"s{ranks}.json"),
                                     log)
            data["scaling"] = rows
        if 3 in sections:
            plan = R.rve_plan(quick, args.tiny)
            log(f"[3] representative volume: {len(plan)} beds x 3 conditions, about "
                f"{R.plan_seconds(plan) / 60:.1f} min on 2 ranks of a loaded 2-core machine "
                "(report_rve.plan_seconds)")
            rows = M.run_worker("rve", plan, args.ranks, os.path.join(tmp, "rve.json"), log)
            data["rve"] = {"rows": rows, "scan": R.RVE_SCAN, "height_mm": R.HEIGHT_MM,
                           "plan_seconds": R.plan_seconds(plan)}
        if 4 in sections:
            log("[4] surrogate against solver")
            if os.path.exists(args.test) and S.find_models(args.models):
                n = 3 if quick else 20
                rt = [1e-2, 1e-4, 1e-8] if quick else [1e-2, 1e-3, 1e-4, 1e-6, 1e-8]
                data["surrogate"] = S.surrogate_vs_solver(args.test, args.models, n, rt, log)
                data["surrogate"]["test"] = args.test
            else:
                data["surrogate"] = None
                log(f"  skipped: no held-out data set at {args.test} or no trained model "
                    "(run/train/train_surrogate.py makes both; see docs/surrogate.md)")
            from run.report.sizes import measure_sizes, parse_size_tests
            if args.size_test or not args.tiny:   # the test suite's report reads no /work/data
                data["sizes"] = measure_sizes(parse_size_tests(args.size_test), log)
    data["elapsed_seconds"] = seconds = time.perf_counter() - t_start
    if base is not None:  # the sections not rerun keep their numbers, and the page says so
        rerun = {"sections": sorted(sections), "date": data["machine"]["date"],
                 "commit": data["machine"]["commit"], "seconds": data["elapsed_seconds"]}
        base.update({k: v for k, v in data.items() if k not in ("machine", "elapsed_seconds")})
        # an earlier partial run whose sections were all rerun now says nothing of the page
        base["updated"] = [u for u in base.get("updated", [])
                           if not set(u["sections"]) <= set(rerun["sections"])] + [rerun]
        data = base
    from run.report.write import write_report
    paths = write_report(data, args.out, sections)
    log(f"wrote {', '.join(os.path.relpath(p) for p in paths)} in "
        f"{seconds:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

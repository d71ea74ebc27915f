"""Data-set benchmark: beds per hour of the old and the new labelling path, batch overhead.

    python -m run.bench.dataset                  # small scale, 20 beds on 1 and on 2 ranks,
                                                 # old path (GAMG, rtol 1e-8) and new (auto)
    python -m run.bench.dataset --count 40 --ranks 2
    python -m run.bench.dataset --paper          # + one bed of the paper scale (1 rank)

Each run is ``mpirun -n N python -m run.bench.dataset --worker ...``, which
calls amfe.dataset.driver.run_dataset exactly as ``amfe dataset`` does (fresh
temporary directory, groups of one rank) and reports its timing record. The
parent measures the whole command's wall time. All times are rank-seconds
(wall x ranks), split into:

- solver: inside homogenize_bed (frame, assembly, GAMG set-up, six solves,
  averaging) -- the work;
- generate, image: making the bed and its image (amfe.model.bed, amfe.dataset.images);
- records: the rest of each record's time (hand-out, part file with fsync,
  agreement in the group);
- tail: ranks idle at the end, waiting for the last beds of the others
  (about half a bed per rank, whatever the count: it vanishes for long runs);
- setup+merge: run_dataset before and after the hand-out loop (checks,
  window, merge into DATA.h5, final check);
- start-up: interpreter, mpi4py, PETSc imports and mpirun.

"machinery" = records + tail + setup+merge + start-up: everything that is
neither the solve nor the data (generation, image). "steady" leaves out the
one-off terms (start-up, setup+merge, tail) that do not grow with the count.
The machine may be shared: the load average before each run is printed.

Each configuration runs the same beds in the same invocation: "old" is the
first round's path (``--solver gamg``, rtol 1e-8, ``-amfe_block no``), "new"
is the default (``--solver auto``); the ratio of their beds per hour is printed.
On a shared machine wall times drift with the load between the two runs, so
``--interleave`` (the first thing printed) labels each bed with both paths in
turn in one process and compares their CPU seconds, which time-sharing leaves
alone.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from run.common import ROOT, parser  # noqa: E402
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
MARK = "BENCH-RESULT "


def worker(args):
    import h5py
    from amfe.dataset.driver import run_dataset
    res = run_dataset(args.output, args.count, seed=args.seed, scale=args.scale,
                      progress=False, out=open(os.devnull, "w"), solver=args.solver)
    if res is not None:
        with h5py.File(args.output, "r") as f:
            n = f["n_particles"][()]
            bonds = f["n_bonds"][()]
            sec = f["seconds"][()]
            status = f["status"][()]
        res = {k: v for k, v in res.items() if k not in ("failures", "lines")}
        res.update(n_mean=float(n[n > 0].mean()), n_min=int(n[n > 0].min()), n_max=int(n.max()),
                   bonds_mean=float(bonds[bonds > 0].mean()), ok=int((status == 0).sum()),
                   solve_mean=float(sec[:, 2].mean()), solve_min=float(sec[:, 2].min()),
                   solve_max=float(sec[:, 2].max()), gen_mean=float(sec[:, 0].mean()),
                   image_mean=float(sec[:, 1].mean()))
        print(MARK + json.dumps(res), flush=True)


PATHS = {"old": ["--solver", "gamg", "-amfe_block", "no"], "new": ["--solver", "auto"]}


def interleaved(count, seed):
    """Label beds 0..count-1 of the small scale with both paths in turn; CPU seconds each."""
    from mpi4py import MPI

    from amfe.dataset.record import load_pixelate, make_record
    from amfe.solvers.petsc import init_petsc
    PETSc = init_petsc([])
    pix = load_pixelate()
    total = {"old": 0.0, "new": 0.0}
    methods = []
    for k in range(count):
        for path, solver, block in (("old", "gamg", "no"), ("new", "auto", None)):
            opts = PETSc.Options()
            if block:
                opts.setValue("amfe_block", block)
            t0 = time.process_time()
            rec = make_record(k, seed, "small", MPI.COMM_SELF, pixelate=pix,
                              solve={"rtol": None, "solver": solver})
            total[path] += time.process_time() - t0
            opts.delValue("amfe_block")
            if path == "new":
                methods.append(json.loads(rec["solver"])["method"])
    old, new = (3600 * count / total[p] for p in ("old", "new"))
    print(f"interleaved, small scale, {count} beds on 1 rank (CPU seconds, both paths per bed): "
          f"old {total['old'] / count:.2f} s/bed = {old:.0f} beds/hour/core, new "
          f"{total['new'] / count:.2f} s/bed = {new:.0f} beds/hour/core: new / old = "
          f"{new / old:.2f}x; auto chose cholesky for {methods.count('cholesky')} of {count}")


def run(scale, count, ranks, seed, workdir, path="new"):
    out = os.path.join(workdir, f"{scale}_{ranks}_{path}.h5")
    cmd = [sys.executable, "-m", "run.bench.dataset", "--worker", "--output", out,
           "--count", str(count), "--seed", str(seed), "--scale", scale, *PATHS[path]]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=ENV, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(MARK)]
    if proc.returncode != 0 or not lines:
        sys.exit(f"failed: {' '.join(cmd)}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    r = json.loads(lines[0][len(MARK):])
    r.update(wall=wall, load=load)
    return r


def report(scale, count, ranks, r, path="new"):
    total = r["wall"] * ranks
    solve, gen, img = r["solve_rank_seconds"], r["generate_rank_seconds"], r["image_rank_seconds"]
    records = r["busy_rank_seconds"] - solve - gen - img
    tail = r["work_seconds"] * ranks - r["busy_rank_seconds"]
    setup_merge = (r["seconds"] - r["work_seconds"]) * ranks
    startup = total - r["seconds"] * ranks
    machinery = records + tail + setup_merge + startup
    rate = count / r["wall"] * 3600

    def pc(x, of=total):
        return f"{100 * x / of:.1f} %"

    print(f"{scale} scale, {path} path ({' '.join(PATHS[path])}), {ranks} rank(s), {count} beds "
          f"({r['ok']} ok), load average before {r['load']:.2f}")
    print(f"  particles mean {r['n_mean']:.0f} (min {r['n_min']}, max {r['n_max']}), bonds mean "
          f"{r['bonds_mean']:.0f}")
    print(f"  per bed: generate {r['gen_mean']:.3f} s, image {r['image_mean']:.3f} s, homogenize "
          f"{r['solve_mean']:.3f} s (min {r['solve_min']:.3f}, max {r['solve_max']:.3f})")
    print(f"  whole command {r['wall']:.1f} s -> {rate:.0f} beds/hour = {rate / ranks:.0f} "
          f"beds/hour/core; 2000 beds: {2000 / rate:.2f} h")
    print(f"  rank time {total:.1f} s: solver {pc(solve)}, generate {pc(gen)}, image {pc(img)}, "
          f"records {pc(records)}, tail {pc(tail)}, setup+merge {pc(setup_merge)}, start-up "
          f"{pc(startup)}")
    steady = solve + gen + img + records
    print(f"  overhead (all but the solver) {pc(total - solve)}; batch machinery {pc(machinery)}; "
          f"steady state (per record, no one-off terms): all but the solver "
          f"{pc(steady - solve, steady)}, machinery {pc(records, steady)}")


def main():
    ap = parser(__doc__)
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--ranks", default="1,2", help="comma list of rank counts (default 1,2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--paper", action="store_true", help="also time one paper-scale bed")
    ap.add_argument("--no-small", action="store_true", help="skip the small-scale runs")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--output", help=argparse.SUPPRESS)
    ap.add_argument("--scale", default="small", help=argparse.SUPPRESS)
    ap.add_argument("--solver", default="auto", help=argparse.SUPPRESS)
    ap.add_argument("--paths", default="old,new", help="which paths to time (default old,new)")
    ap.add_argument("--interleave", type=int, default=20, metavar="N",
                    help="first label N beds with both paths in turn, in one process (CPU "
                         "seconds; default 20; 0 skips)")
    args, petsc = ap.parse_known_args()
    if args.worker:
        from amfe.solvers.petsc import init_petsc
        init_petsc(petsc)
    if args.worker:
        return worker(args)
    if args.interleave:
        interleaved(args.interleave, args.seed)
    with tempfile.TemporaryDirectory(prefix="amfe-bench-") as d:
        if not args.no_small:
            for ranks in (int(x) for x in args.ranks.split(",")):
                rates = {}
                for path in args.paths.split(","):
                    r = run("small", args.count, ranks, args.seed, d, path)
                    report("small", args.count, ranks, r, path)
                    rates[path] = args.count / r["wall"] * 3600
                if len(rates) == 2:
                    print(f"  {ranks} rank(s): new / old = {rates['new'] / rates['old']:.2f}x "
                          f"({rates['old']:.0f} -> {rates['new']:.0f} beds/hour)")
        if args.paper:
            r = run("paper", 1, 1, args.seed, d)
            print(f"paper scale, 1 bed on 1 rank: {r['n_max']} particles, "
                  f"{r['bonds_mean']:.0f} bonds, {'ok' if r['ok'] else 'FAILED'}, load average "
                  f"before {r['load']:.2f}")
            print(f"  generate {r['gen_mean']:.1f} s, image {r['image_mean']:.1f} s, homogenize "
                  f"{r['solve_mean']:.1f} s; whole command {r['wall']:.1f} s")


if __name__ == "__main__":
    main()
